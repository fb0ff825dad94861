"""Anomaly maps of image files: the application behind ``jaxanom predict``.

``predict_images(paths, out, predict, settings)`` streams the images through a network (any
run that ``jaxanom evaluate --run`` loads): each image is decoded, resized to the network's
working size (bilinear; or kept at its own size), batched on the device, scored with each
method (``jaxanom.app.methods``) at the working size, and each map is resized back (bilinear) to
the image's native size and written in every requested format:

- ``npy``:   ``<out>/npy/<method>/<frame>.npy``, float16 (H, W);
- ``png``:   ``<out>/png/<method>/<frame>.png``, the image and the map over it, with a colour bar;
- ``smiyc``: ``<out>/anomaly_p/<method>/<dataset>/<frame>.hdf5``, float16 (H, W) in the HDF5
  dataset ``value`` (gzip level 9): SegmentMeIfYouCan's submission tree. The benchmark's code
  (github SegmentMeIfYouCan/road-anomaly-benchmark, ``road_anomaly_benchmark/evaluation.py``
  and ``datasets/dataset_io.py``) stores ``anomaly_p.astype(float16)`` at
  ``anomaly_p/{method_name}/{dset_name}/{fid}.hdf5`` through ``ChannelLoaderHDF5(var_name=
  "value", compression=9)``; ``fid`` is the image's file stem and ``dset_name`` e.g.
  ``AnomalyTrack-all``, ``ObstacleTrack-all``, ``LostAndFound-test`` (``datasets/tracks.py``).

``<frame>`` is the image's file name without its extension. Every file is written under a
temporary name beside it and renamed, so a killed run leaves complete files only, and a rerun
skips the frames whose files all exist (and removes the temporary files a kill left).
``settings.json`` in ``out`` records the settings; a
rerun with other settings is refused (``check_resumable``).
"""
from __future__ import annotations

import dataclasses
import glob
import io
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".webp")
FORMATS = ("npy", "png", "smiyc")
SETTINGS_FILE = "settings.json"
SMIYC_DATASETS = ("AnomalyTrack-all", "ObstacleTrack-all", "LostAndFound-test", "LostAndFound-train")
FLOAT16_MAX = float(np.finfo(np.float16).max)


@dataclasses.dataclass(frozen=True)
class PredictSettings:
    """What ``predict_images`` computes and writes.

    ``methods``: names from ``jaxanom.app.methods.METHODS`` (not the MMF pipeline rows);
    ``formats``: from ``FORMATS``; ``size``: the working (H, W) the network sees, or None for
    each image's own size; ``batch_size``: images per device batch; ``dataset``: the SMIYC
    dataset name (format ``smiyc``); ``slic_step``: SLIC grid step of the ``*_superpixel``
    methods (None: ``superpixels.scaled_step`` of the working size); ``cudam_sigma``: Eq. 10's
    weight (None: the paper-equivalent one); ``unit_interval``: (center, scale) to write
    ``metrics.smiyc.to_unit_interval`` of every map instead of the score (None: the score).
    """

    methods: tuple[str, ...]
    formats: tuple[str, ...] = ("npy",)
    size: tuple[int, int] | None = None
    batch_size: int = 1
    dataset: str | None = None
    slic_step: int | None = None
    cudam_sigma: float | None = None
    unit_interval: tuple[float, float] | None = None

    def __post_init__(self):
        from jaxanom.app.methods import METHODS, NEEDS_MMF

        bad = [m for m in self.methods if m not in METHODS or m in NEEDS_MMF]
        if bad or not self.methods:
            raise ValueError(f"methods: expected names from {[m for m in METHODS if m not in NEEDS_MMF]}, "
                             f"got {list(self.methods)}")
        if len(set(self.methods)) != len(self.methods) or len(set(self.formats)) != len(self.formats):
            raise ValueError(f"methods, formats: expected no repeats, got {list(self.methods)}, {list(self.formats)}")
        if not self.formats or any(f not in FORMATS for f in self.formats):
            raise ValueError(f"formats: expected names from {FORMATS}, got {list(self.formats)}")
        if self.size is not None and (len(self.size) != 2 or min(self.size) < 1):
            raise ValueError(f"size: expected (height, width) >= 1, got {self.size}")
        if self.batch_size < 1:
            raise ValueError(f"batch_size: expected >= 1, got {self.batch_size}")
        if "smiyc" in self.formats and not _plain_name(self.dataset):
            raise ValueError(f"dataset: the smiyc format needs the benchmark's dataset name (e.g. "
                             f"{', '.join(SMIYC_DATASETS)}), a plain folder name, got {self.dataset!r}")
        if self.slic_step is not None and self.slic_step < 1:
            raise ValueError(f"slic_step: expected >= 1, got {self.slic_step}")
        if self.unit_interval is not None and not (len(self.unit_interval) == 2 and np.isfinite(self.unit_interval).all()
                                                   and self.unit_interval[1] > 0):
            raise ValueError(f"unit_interval: expected (center, scale > 0), finite, got {self.unit_interval}")


def _plain_name(name) -> bool:
    return isinstance(name, str) and name not in ("", ".", "..") and "/" not in name and "\\" not in name


def list_images(inputs: Sequence[str]) -> list[Path]:
    """Image files named by ``inputs``: files, folders (their image files, not recursive) or
    glob patterns (``**`` recursive); sorted per input, without repeats.

    FileNotFoundError for an input that names nothing; ValueError for a named file without an
    image extension, or two images with the same file stem (their outputs would collide).
    """
    found: list[Path] = []
    for text in inputs:
        path = Path(text)
        if path.is_dir():
            matches = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
        elif path.is_file():
            if path.suffix.lower() not in IMAGE_EXTENSIONS:
                raise ValueError(f"images: expected files ending in {IMAGE_EXTENSIONS}, got {text}")
            matches = [path]
        elif glob.has_magic(text):
            matches = sorted(Path(p) for p in glob.glob(text, recursive=True)
                             if Path(p).is_file() and Path(p).suffix.lower() in IMAGE_EXTENSIONS)
        else:
            matches = []
        if not matches:
            raise FileNotFoundError(f"images: {text} names no image file ({', '.join(IMAGE_EXTENSIONS)})")
        found.extend(matches)
    unique = list(dict.fromkeys(p.resolve() for p in found))
    stems: dict[str, Path] = {}
    for path in unique:
        if path.stem in stems:
            raise ValueError(f"images: {stems[path.stem]} and {path} share the frame name {path.stem!r}; "
                             "their outputs would overwrite each other")
        stems[path.stem] = path
    return unique


def output_file(out: Path, frame: str, method: str, fmt: str, dataset: str | None) -> Path:
    """The file of one frame, method and format (module docstring)."""
    if fmt == "smiyc":
        return out / "anomaly_p" / method / dataset / f"{frame}.hdf5"
    return out / fmt / method / f"{frame}.{fmt}"


def output_files(out: Path, frame: str, settings: PredictSettings) -> list[Path]:
    """Every file ``predict_images`` writes for ``frame``."""
    return [output_file(out, frame, m, f, settings.dataset) for m in settings.methods for f in settings.formats]


def settings_record(settings: PredictSettings, **extra) -> dict:
    """The JSON of ``settings`` plus ``extra`` (run, statistics file)."""
    record = dataclasses.asdict(settings)
    record = {k: (list(v) if isinstance(v, tuple) else v) for k, v in record.items()}
    return {**record, **extra}


def check_resumable(out: Path, record: dict) -> bool:
    """True when ``out`` holds the ``settings.json`` of an earlier run with ``record``'s settings
    (its frames may be skipped), False when it holds none; ValueError naming the first difference."""
    import json

    path = out / SETTINGS_FILE
    if not path.is_file():
        return False
    try:
        earlier = json.loads(path.read_text())
    except ValueError:
        raise ValueError(f"out: {path} is not readable JSON; remove it or choose another folder") from None
    for key in sorted(set(earlier) | set(record)):
        if earlier.get(key) != record.get(key):
            raise ValueError(f"out: {out} holds maps made with {key}={earlier.get(key)!r}, now {key}={record.get(key)!r}; "
                             "choose another folder (or the same settings to resume)")
    return True


def _frames(paths: Iterable[Path], size) -> Iterator[dict]:
    """Decoded frames: ``{"name", "image" (native RGB uint8), "input" (at the working size)}``."""
    import cv2

    from jaxanom.data.image_io import read_rgb

    for path in paths:
        image = read_rgb(path)  # ValueError naming a corrupt file
        resized = image if size is None or image.shape[:2] == tuple(size) else \
            cv2.resize(image, (size[1], size[0]), interpolation=cv2.INTER_LINEAR)
        yield {"name": path.stem, "image": image, "input": resized}


def _batches(frames: Iterable[dict], batch_size: int) -> Iterator[list[dict]]:
    """Consecutive frames of one working size, at most ``batch_size`` at a time. When a frame
    cannot be decoded, the frames before it are yielded first, then its ValueError raised."""
    batch: list[dict] = []
    frames = iter(frames)
    while True:
        try:
            frame = next(frames)
        except StopIteration:
            break
        except ValueError:
            if batch:
                yield batch
            raise
        if batch and frame["input"].shape != batch[0]["input"].shape:
            yield batch
            batch = []
        batch.append(frame)
        if len(batch) == batch_size:
            yield batch
            batch = []
    if batch:
        yield batch


class Scorer:
    """Network + methods on one batch, dispatched asynchronously (``__call__``), read back later."""

    def __init__(self, predict: Callable, settings: PredictSettings, stats=None, check_size=None):
        self.predict, self.settings, self.stats, self.check_size = predict, settings, stats, check_size
        self._checked: set = set()

    def __call__(self, batch: list[dict]) -> dict:
        """Device arrays ``{method: (B, h, w)}`` for the frames of ``batch`` (padded to the batch size)."""
        from jaxanom.app import methods as scoring
        from jaxanom.cudam_score import paper_sigma

        images = np.stack([f["input"] for f in batch])
        if self.check_size is not None and images.shape[1:3] not in self._checked:
            self.check_size(images.shape[1:3], batch[0]["name"])
            self._checked.add(images.shape[1:3])
        padding = self.settings.batch_size - len(batch)  # one compiled shape per working size
        if padding:
            images = np.concatenate([images, np.repeat(images[-1:], padding, axis=0)])
        out = self.predict(images)
        sigma = self.settings.cudam_sigma
        if "cudam" in self.settings.methods and sigma is None:
            sigma = paper_sigma(int(out["attention_positions"]))
        maps = {name: scoring.score_batch(name, out["logits"], stats=self.stats, attention_up=out.get("attention_up"),
                                          cudam_sigma=sigma, images=images, slic_step=self.settings.slic_step)
                for name in self.settings.methods}
        if self.settings.unit_interval is None:
            return maps
        from jaxanom.metrics.smiyc import to_unit_interval

        return {name: to_unit_interval(score, *self.settings.unit_interval) for name, score in maps.items()}


def native_map(score: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A float32 map resized (bilinear, half-pixel centres) to ``shape`` (H, W)."""
    import cv2

    score = np.asarray(score, np.float32)
    if score.shape == tuple(shape):
        return score
    return cv2.resize(score, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)


def write_frame(out: Path, frame: dict, maps: dict, settings: PredictSettings) -> None:
    """Every output file of one frame; ``maps[method]`` (H, W) at the image's native size."""
    from jaxanom.io import write_bytes_atomic, write_with_atomic

    for method, score in maps.items():
        half = None
        if {"npy", "smiyc"} & set(settings.formats):
            if not (np.isfinite(score).all() and np.abs(score).max(initial=0.0) <= FLOAT16_MAX):
                raise ValueError(f"method {method}: scores of {frame['name']} are not finite in float16 "
                                 f"(|score| <= {FLOAT16_MAX:g}); the npy and smiyc formats store float16")
            half = score.astype(np.float16)
        for fmt in settings.formats:
            path = output_file(out, frame["name"], method, fmt, settings.dataset)
            if fmt == "npy":
                buffer = io.BytesIO()
                np.save(buffer, half)
                write_bytes_atomic(path, buffer.getvalue())
            elif fmt == "smiyc":
                write_with_atomic(path, lambda tmp: _write_hdf5(tmp, half))
            else:
                from jaxanom.viz import Panel, write_panels

                panels = [Panel(frame["name"], frame["image"]),
                          Panel(f"{method} over the image", score, base=frame["image"],
                                label=f"{method} (higher = more anomalous)")]
                write_panels(path, panels, columns=2, min_width=512, max_width=1024)


def _write_hdf5(path: str, value: np.ndarray) -> None:
    import h5py

    with h5py.File(path, "w") as f:
        f.create_dataset("value", data=value, compression=9)  # gzip level 9, as the benchmark writes


def predict_images(paths: Sequence[Path], out: Path, scorer: Scorer, *, progress: bool = True) -> dict:
    """Score ``paths`` into ``out`` (see the module docstring); frames whose files all exist are
    skipped, and unfinished temporary files of a killed run (``.<file>.*.tmp``) are removed:
    the caller must hold ``out`` alone (the CLI claims it). Returns ``{"frames", "written",
    "skipped"}``. A corrupt image raises ValueError naming it, after the frames before it are
    written."""
    from tqdm import tqdm

    settings = scorer.settings
    for root in {"npy": out / "npy", "png": out / "png", "smiyc": out / "anomaly_p"}.values():
        for stale in root.rglob(".*.tmp") if root.is_dir() else ():  # a killed run's unfinished files
            stale.unlink(missing_ok=True)
    todo = [p for p in paths if not all(f.is_file() for f in output_files(out, p.stem, settings))]
    bar = tqdm(total=len(todo), unit="image", desc="predict", disable=not progress)
    pending = None

    def finish(batch, scores):
        host = {name: np.asarray(value) for name, value in scores.items()}
        for index, frame in enumerate(batch):
            shape = frame["image"].shape[:2]
            write_frame(out, frame, {name: native_map(host[name][index], shape) for name in host}, settings)
            bar.update(1)

    try:
        for batch in _batches(_frames(todo, settings.size), settings.batch_size):
            scores = scorer(batch)  # dispatched: the device works while the next batch is decoded
            done, pending = pending, (batch, scores)
            if done is not None:
                finish(*done)
        done, pending = pending, None
        if done is not None:
            finish(*done)
    except ValueError:
        if pending is not None:  # e.g. a corrupt image in the next batch: keep what was computed
            finish(*pending)
        raise
    finally:
        bar.close()
    return {"frames": len(paths), "written": len(todo), "skipped": len(paths) - len(todo)}


def inside(path: Path, folder: Path) -> bool:
    """True when ``path`` is ``folder`` or lies under it (both resolved)."""
    path, folder = Path(path).resolve(), Path(folder).resolve()
    return path == folder or folder in path.parents


def logits_shape(model, variables, size: tuple[int, int]) -> tuple[int, ...]:
    """The shape of ``model``'s logits for one (h, w) image (``jax.eval_shape``: no compute;
    any float input will do for shapes, so the network's own normalisation is not needed)."""
    import jax
    import jax.numpy as jnp

    spec = jax.ShapeDtypeStruct((1, *size, 3), jnp.float32)
    return tuple(jax.eval_shape(lambda v, x: model.apply(v, x, train=False), variables, spec)["logits"].shape)


def size_check(model, variables) -> Callable[[tuple[int, int], str], None]:
    """``check((h, w), frame)``: ValueError unless ``model`` takes (1, h, w, 3) images and returns
    logits of that size (shapes only)."""

    def check(shape: tuple[int, int], frame: str) -> None:
        try:
            logits = logits_shape(model, variables, tuple(shape))
        except Exception as error:  # flax / XLA shape errors of many types: one line naming the size
            reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise ValueError(f"size: the network does not run on {shape[0]}x{shape[1]} images ({frame}): "
                             f"{reason}; choose a working size it takes (--size)") from None
        if logits[1:3] != tuple(shape):
            raise ValueError(f"size: the network's logits are {logits[1:3]} for {shape[0]}x{shape[1]} images "
                             f"({frame}); expected the input's size")

    return check


__all__ = ["FORMATS", "PredictSettings", "Scorer", "check_resumable", "inside", "list_images", "native_map",
           "logits_shape", "output_file", "output_files", "predict_images", "settings_record", "size_check",
           "write_frame"]
