"""An MMF experiment: the pipeline's config with the anomaly frames it is scored on, and a
folder written by ``jaxanom demo mmf`` read back to score a dataset (``jaxanom evaluate --mmf``)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from jaxanom._validate import check_count
from jaxanom.app.evaluate import dataset_reader
from jaxanom.app.experiment import Experiment
from jaxanom.app.mmf_pipeline import MMFConfig, MMFPipeline, scored_batches
from jaxanom.data.synthetic import ANOMALY_SPLITS, SyntheticScenes
from jaxanom.errors import InputError, reading


@dataclasses.dataclass(frozen=True)
class MMFDemoConfig:
    """The pipeline, and the anomaly frames scored (another seed than any training frame)."""

    pipeline: MMFConfig = MMFConfig()
    anomaly_split: str = "anomaly"
    anomaly_frames: int = 32
    pictures: int = 4

    def __post_init__(self):
        if self.anomaly_split not in ANOMALY_SPLITS:
            raise ValueError(f"anomaly_split: expected one of {ANOMALY_SPLITS}, got {self.anomaly_split!r}")
        check_count("anomaly_frames", self.anomaly_frames)
        check_count("pictures", self.pictures, minimum=0)

    @classmethod
    def quick(cls) -> "MMFDemoConfig":
        return cls(pipeline=MMFConfig.quick(), anomaly_frames=2, pictures=1)

    @classmethod
    def from_dict(cls, values: dict) -> "MMFDemoConfig":
        """The inverse of ``dataclasses.asdict`` (``results.json``'s ``"config"``); fields left out
        keep their defaults, a ``pipeline.segmenter`` given is a whole ``Experiment``."""
        if not isinstance(values, dict):
            raise ValueError(f"config: expected a JSON object, got {type(values).__name__}")
        values = dict(values)
        pipeline = dict(values.pop("pipeline", {}))
        try:
            if "segmenter" in pipeline:
                pipeline["segmenter"] = Experiment.from_dict(pipeline["segmenter"])
            if isinstance(pipeline.get("dissim_variants"), list):  # JSON has no tuples
                pipeline["dissim_variants"] = tuple(pipeline["dissim_variants"])
            return cls(pipeline=MMFConfig(**pipeline), **values)
        except (TypeError, KeyError) as error:  # an unknown or missing field
            raise ValueError(f"config: {type(error).__name__}: {error}") from None


def evaluation_frames(config: MMFDemoConfig) -> SyntheticScenes:
    """Anomaly frames with disparity and the road ROI, seed = segmenter seed + 2."""
    seg = config.pipeline.segmenter
    return SyntheticScenes(config.anomaly_split, config.anomaly_frames, seg.train.seed + 2, height=seg.height,
                           width=seg.width, disparity=True, roi=True)


def load_config(path: str | Path) -> MMFDemoConfig:
    """An ``MMFDemoConfig`` from a JSON file: the ``"config"`` of a ``results.json``, or any part of it."""
    try:
        values = json.loads(Path(path).read_text())
    except (OSError, ValueError) as error:
        raise ValueError(f"config {path}: cannot be read as JSON ({error})") from None
    try:
        return MMFDemoConfig.from_dict(values.get("config", values) if isinstance(values, dict) else values)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def mmf_scored_batches(folder: str, dataset: str, path: str, *, frames: int | None = None, depth: str | None = None):
    """``(source, batches)``: ``dataset`` scored by the MMF pipeline of ``folder`` (written by
    ``jaxanom demo mmf``), read-only; a dataset without disparity is refused."""
    folder = Path(folder)
    if not (folder / "results.json").is_file():
        raise InputError("mmf", f"{folder}: expected a folder written by `jaxanom demo mmf` (with results.json)")
    with reading("mmf", folder):
        config = load_config(folder / "results.json").pipeline
    if dataset not in ("synthetic", "lost-and-found", "smiyc") or (dataset == "smiyc" and not depth):
        raise InputError("mmf", f": the {dataset} dataset has no disparity; use synthetic, lost-and-found or "
                         "smiyc with {depth}", mentions=("depth",))
    seg = config.segmenter
    source = dataset_reader(dataset, path, frames=frames, depth=depth,
                            size={"height": seg.height, "width": seg.width, "disparity": True, "roi": True})
    return source, scored_batches(MMFPipeline.load(config, folder / "runs"), source, batch_size=1)
