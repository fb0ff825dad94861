"""An off-road experiment: the frame sources, sizes and pipeline settings of the off-road paper's
three stages (``OffroadDemoConfig``), their frames and simulated patch annotations."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from jaxanom._validate import check_count
from jaxanom.app.offroad_pipeline import OffroadConfig
from jaxanom.data.offroad import DOMAINS, GRANULARITIES, OffroadSequence
from jaxanom.data.patch_annotations import annotate
from jaxanom.errors import InputError
from jaxanom.offroad.active import min_frames
from jaxanom.offroad.encoder import AnnotatedFrames, EncoderConfig, stack_annotations


@dataclasses.dataclass(frozen=True)
class Source:
    """``frames`` frames from ``start`` every ``step`` of a sequence.

    ``reader="synthetic"``: sequence ``sequence`` of domain ``domain`` (``jaxanom.data.offroad``);
    ``"deepscene"``: split ``name`` of the DeepScene folder ``root``; ``"rugd"``: sequence
    ``name`` of the RUGD folder ``root``. Real frames are resized to the demo's size; their
    ground truth drives the simulated annotator and the evaluation.
    """

    domain: str = "A"
    sequence: int = 0
    frames: int = 1
    start: int = 0
    step: int = 1
    reader: str = "synthetic"
    root: str = ""
    name: str = ""

    def __post_init__(self):
        if self.reader not in ("synthetic", "deepscene", "rugd"):
            raise ValueError(f"reader: expected 'synthetic', 'deepscene' or 'rugd', got {self.reader!r}")
        if self.reader == "synthetic" and self.domain not in DOMAINS:
            raise ValueError(f"domain: expected one of {sorted(DOMAINS)}, got {self.domain!r}")
        for name, minimum in (("frames", 1), ("step", 1), ("start", 0), ("sequence", 0)):
            check_count(name, getattr(self, name), minimum=minimum)

    def open(self):
        """The real reader of this source (not for ``"synthetic"``)."""
        from jaxanom.data.deepscene import DeepScene
        from jaxanom.data.rugd import RUGD

        return DeepScene(self.root, self.name or "train") if self.reader == "deepscene" else RUGD(self.root, self.name)


@dataclasses.dataclass(frozen=True)
class OffroadDemoConfig:
    """Sizes of the demo (``quick()``: a smoke run of the same path at tiny sizes)."""

    pipeline: OffroadConfig = OffroadConfig(encoder=EncoderConfig.tiny(steps=150), components=tuple(range(2, 11)),
                                            gmm_inits=2, budget=6, gap=3)
    train: tuple[Source, ...] = tuple(Source("A", s, 6, 0, 8) for s in range(4))
    active: Source = Source("B", 0, 60)
    test: Source = Source("C", 0, 40)
    segmented: int = 4
    pictures: int = 2
    anchors: int = 12
    granularity: str = "lv3"
    height: int = 128
    width: int = 256
    seed: int = 0

    def __post_init__(self):
        if not isinstance(self.pipeline, OffroadConfig):
            raise ValueError(f"pipeline: expected an OffroadConfig, got {type(self.pipeline).__name__}")
        if not self.train or not all(isinstance(source, Source) for source in (*self.train, self.active, self.test)):
            raise ValueError("train, active, test: expected one or more sources, a source, a source")
        for name, minimum in (("segmented", 1), ("pictures", 0), ("anchors", 1), ("seed", 0)):
            check_count(name, getattr(self, name), minimum=minimum)
        for name in ("height", "width"):
            check_count(name, getattr(self, name), minimum=self.pipeline.encoder.size)
        if self.granularity not in GRANULARITIES:
            raise ValueError(f"granularity: expected one of {sorted(GRANULARITIES)}, got {self.granularity!r}")
        needed = min_frames(self.pipeline.budget, self.pipeline.gap)
        if self.active.frames < needed:
            raise ValueError(f"pipeline.budget, pipeline.gap: {self.pipeline.budget} hard frames {self.pipeline.gap} "
                             f"apart need {needed} frames, the active source has {self.active.frames}")

    @classmethod
    def quick(cls) -> "OffroadDemoConfig":
        encoder = EncoderConfig(size=16, widths=(4, 8, 8, 8, 8), hidden=8, dim=3, negatives=4, frames_per_step=2, steps=3)
        pipeline = OffroadConfig(encoder=encoder, neighbours=2, components=(2, 3), max_components=3, gmm_inits=1, budget=2,
                                 gap=1, crf_iters=1)
        return cls(pipeline=pipeline, train=(Source("A", 0, 2, 0, 4),), active=Source("B", 0, 4), test=Source("C", 0, 3),
                   segmented=1, pictures=1, anchors=6, height=48, width=64)


def check_sources(config: OffroadDemoConfig) -> None:
    """Before any work: each real source's folder holds its reader's layout (FileNotFoundError
    naming what is missing) and frames from its ``start`` on (InputError naming the config's field,
    ``train[i]``, ``active`` or ``test``)."""
    named = [(f"train[{i}]", source) for i, source in enumerate(config.train)]
    for field, source in [*named, ("active", config.active), ("test", config.test)]:
        if source.reader != "synthetic":
            _frames_from_start(source, field)


def _frames_from_start(source: Source, field: str):
    """The reader of the real ``source``; InputError naming ``field`` when ``start`` is past its frames."""
    reader = source.open()
    if source.start >= len(reader):
        raise InputError(field, f": {source.reader} source in {source.root}: start {source.start} is past its "
                         f"{len(reader)} frames")
    return reader


def source_frames(source: Source, config: OffroadDemoConfig) -> list[dict]:
    """The frames ``{"image" (H, W, 3) uint8, "label" (H, W)}`` of ``source`` at the config's size and granularity."""
    if source.reader != "synthetic":
        reader = _frames_from_start(source, "source")
        picked = range(source.start, min(len(reader), source.start + source.frames * source.step), source.step)
        size = (config.width, config.height)
        return [{"image": cv2.resize(f["image"], size, interpolation=cv2.INTER_AREA),
                 "label": cv2.resize(f["label"], size, interpolation=cv2.INTER_NEAREST)} for f in map(reader.__getitem__, picked)]
    seq = OffroadSequence(source.domain, source.sequence, (source.frames - 1) * source.step + 1, config.seed,
                          start=source.start, granularity=config.granularity, height=config.height, width=config.width)
    return [seq[i] for i in range(0, len(seq), source.step)]


def class_names(config: OffroadDemoConfig) -> tuple[str, ...]:
    """Reference classes of the evaluation: the granularity's, DeepScene's 5 or RUGD's colour map."""
    from jaxanom.data.deepscene import DEEPSCENE_CLASSES

    source = config.train[0]
    if source.reader == "synthetic":
        return tuple(GRANULARITIES[config.granularity][0])
    return DEEPSCENE_CLASSES if source.reader == "deepscene" else tuple(source.open().class_names)


def num_classes(config: OffroadDemoConfig) -> int:
    """The number of ``class_names(config)``."""
    return len(class_names(config))


def annotated(frames: list[dict], config: OffroadDemoConfig, salt: int) -> AnnotatedFrames:
    """Simulated patch annotations of ``frames`` (``config.anchors`` each), seeded by (seed, ``salt``, frame)."""
    size = config.pipeline.encoder.size
    anns = [annotate(f["label"], np.random.default_rng([config.seed, salt, i]), k=config.anchors, size=size,
                     num_classes=num_classes(config)) for i, f in enumerate(frames)]
    return stack_annotations([f["image"] for f in frames], anns, slots=config.anchors)


def as_float(frames: list[dict]) -> np.ndarray:
    """(T, H, W, 3) float32 images in [0, 1] of ``frames``."""
    return np.stack([f["image"] for f in frames]).astype(np.float32) / 255.0
