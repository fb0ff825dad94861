"""``jaxanom demo``: the whole method on synthetic driving scenes, end to end.

Train a small DeepLabV3+ with CuDAM on in-distribution scenes, fit SML statistics on the
training frames, then score a synthetic anomaly split with every method, pooled as the
benchmarks pool, and write a results table, a JSON of the numbers and pictures.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np

from jaxanom import sml
from jaxanom._validate import check_count, check_number
from jaxanom.cudam.objective import CuDAM
from jaxanom.cudam.score import PAPER_TEST_POSITIONS, PAPER_TRAIN_POSITIONS, equivalent_weight
from jaxanom.data.synthetic import ANOMALY_SPLITS
from jaxanom.app.evaluate import anomaly_results, class_statistics, predictions, predictor, segmentation_results
from jaxanom.config_codec import encode
from jaxanom.app.experiment import Experiment, build_network, frames, frames_record, run_training
from jaxanom.app.reports import results_table, write_pictures
from jaxanom.io import write_json_atomic
from jaxanom.train.segmenter import TrainConfig
from jaxanom.train.optim import OptimConfig

DEMO_METHODS = ("msp", "max_logit", "entropy", "energy", "sml", "sml_post", "cudam")
_ATTENTION_POSITIONS = (128 // 4) * (256 // 4)  # CuDAM's map of a 128 x 256 demo frame (stride 4)


@dataclasses.dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo; ``quick()`` is a smoke run of the same path at tiny sizes.

    The demo's frames are far smaller than the paper's, so CuDAM's tau and sigma are scaled to
    the attention map's number of positions (``equivalent_weight``): with the paper's raw
    values, the reward and the ensemble would be 16x and 64x stronger than the paper's.
    """

    experiment: Experiment = Experiment(
        attention="cudam", train_frames=256, height=128, width=256, crop=(128, 256), batch_size=8,
        train=TrainConfig(run_dir="", steps=1500, eval_every=500, save_every=500, keep=2,
                          objective=CuDAM(tau=equivalent_weight(5e4, _ATTENTION_POSITIONS, PAPER_TRAIN_POSITIONS)),
                          optim=OptimConfig(name="adamw", lr=2e-3, weight_decay=1e-4, warmup_steps=30)))
    stats_frames: int = 64
    val_frames: int = 32
    anomaly_frames: int = 64
    anomaly_split: str = "anomaly"
    pictures: int = 4
    cudam_sigma: float = equivalent_weight(2e4, _ATTENTION_POSITIONS, PAPER_TEST_POSITIONS)

    def __post_init__(self):
        for name in ("stats_frames", "val_frames", "anomaly_frames"):
            check_count(name, getattr(self, name))
        check_count("pictures", self.pictures, minimum=0)
        check_number("cudam_sigma", self.cudam_sigma, 0.0, open_low=True)
        if self.anomaly_split not in ANOMALY_SPLITS:
            raise ValueError(f"anomaly_split: expected one of {ANOMALY_SPLITS}, got {self.anomaly_split!r}")

    @classmethod
    def quick(cls) -> "DemoConfig":
        experiment = dataclasses.replace(
            cls.experiment, train_frames=4, height=64, width=96, crop=(64, 96), batch_size=4,
            train=dataclasses.replace(cls.experiment.train, steps=3, eval_every=3, save_every=3,
                                      optim=dataclasses.replace(cls.experiment.train.optim, warmup_steps=1)))
        return cls(experiment=experiment, stats_frames=4, val_frames=2, anomaly_frames=2, pictures=1)


def _batches(source, batch_size: int):
    from jaxanom.data.pipeline import evaluation_batches

    return evaluation_batches(source, batch_size=batch_size)


def run_demo(out_dir: str | Path, config: DemoConfig = DemoConfig(), *, progress: bool = True,
             log=print) -> dict:
    """Run the demo into ``out_dir`` (created; must not exist or be empty); returns the results."""
    out_dir = Path(out_dir)
    experiment = config.experiment
    log(f"[1/4] training {experiment.model} + CuDAM on {experiment.train_frames} synthetic scenes "
        f"({experiment.train.steps} steps, batch {experiment.batch_size}, {jax.device_count()} device(s))")
    variables = run_training(experiment, out_dir / "run", progress=progress)
    predict = predictor(build_network(experiment), variables)
    batch = experiment.batch_size

    log(f"[2/4] fitting SML class statistics on {config.stats_frames} training frames")
    train_frames = frames(experiment, "train", config.stats_frames)
    stats = class_statistics(predict, _batches(train_frames, batch))
    mean, std = sml.stats_finalize(stats, missing="pooled")
    fitted_on = {**frames_record(experiment, "train"), "count": len(train_frames),
                 "size": [experiment.height, experiment.width]}
    sml.save_stats(out_dir / "sml_stats.npz", mean, std, stats.count, frames=fitted_on)
    never_predicted = np.flatnonzero(np.asarray(stats.count) < 2).tolist()

    log(f"[3/4] evaluating on {config.val_frames} validation and {config.anomaly_frames} anomaly frames")
    segmentation = segmentation_results(
        predictions(predict, _batches(frames(experiment, "val", config.val_frames), batch)),
        experiment.num_classes)
    anomaly_frames = frames(experiment, config.anomaly_split, config.anomaly_frames)
    metrics, curves = anomaly_results(predictions(predict, _batches(anomaly_frames, batch)), DEMO_METHODS,
                                      stats=(mean, std), options={"cudam": {"cudam_sigma": config.cudam_sigma}},
                                      keep_curves=True)

    log("[4/4] writing pictures and results")
    write_pictures(out_dir, predict, anomaly_frames, (mean, std), config.pictures)
    from jaxanom.viz import plot_curves

    plot_curves(out_dir / "roc.png", {n: c["roc"] for n, c in curves.items()}, kind="roc")
    plot_curves(out_dir / "pr.png", {n: c["pr"] for n, c in curves.items()}, kind="pr")
    results = {"anomaly": {"split": config.anomaly_split, "frames": config.anomaly_frames, "metrics": metrics},
               "segmentation": segmentation, "sml_classes_never_predicted": never_predicted,
               "config": encode(config)}
    write_json_atomic(out_dir / "results.json", results)
    log(results_table(metrics, segmentation))
    log(f"results in {out_dir}/ (results.json, roc.png, pr.png, frame_*.png)")
    return results
