"""An MMF experiment: the pipeline's config with the anomaly frames it is scored on, and a
folder written by ``jaxanom demo mmf`` read back to score a dataset (``jaxanom evaluate --mmf``)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxanom._validate import check_count
from jaxanom.app.configs import load_config
from jaxanom.app.evaluate import dataset_reader
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


def evaluation_frames(config: MMFDemoConfig) -> SyntheticScenes:
    """Anomaly frames with disparity and the road ROI, seed = segmenter seed + 2."""
    seg = config.pipeline.segmenter
    return SyntheticScenes(config.anomaly_split, config.anomaly_frames, seg.train.seed + 2, height=seg.height,
                           width=seg.width, disparity=True, roi=True)


def mmf_scored_batches(folder: str, dataset: str, path: str, *, frames: int | None = None, depth: str | None = None):
    """``(source, batches)``: ``dataset`` scored by the MMF pipeline of ``folder`` (written by
    ``jaxanom demo mmf``), read-only, in batches of the pipeline's ``batch_size``; a dataset without
    disparity is refused."""
    folder = Path(folder)
    if not (folder / "results.json").is_file():
        raise InputError("mmf", f"{folder}: expected a folder written by `jaxanom demo mmf` (with results.json)")
    with reading("mmf", folder):
        config = load_config(folder / "results.json", MMFDemoConfig).pipeline
    if dataset not in ("synthetic", "lost-and-found", "smiyc") or (dataset == "smiyc" and not depth):
        raise InputError("mmf", f": the {dataset} dataset has no disparity; use synthetic, lost-and-found or "
                         "smiyc with {depth}", mentions=("depth",))
    seg = config.segmenter
    with reading("path", path):  # a folder that does not hold the dataset
        source = dataset_reader(dataset, path, frames=frames, depth=depth,
                                size={"height": seg.height, "width": seg.width, "disparity": True, "roi": True})
    with reading("mmf", folder):  # a pipeline's networks missing or damaged in the folder
        pipeline = MMFPipeline.load(config, folder / "runs")
    # the pipeline's own batch size, as the demo scores: the same shapes reuse its compiled functions
    return source, scored_batches(pipeline, source, batch_size=config.batch_size)
