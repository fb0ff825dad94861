"""The CamVid baseline of the training claims: the Cityscapes ERFNet's encoder frozen, its decoder
(new 11-class head) trained on cached features (``real_training_common``), scored on CamVid's 233
test frames by ``jaxanom evaluate --dataset camvid`` (11 classes, void ignored).

    python -m experiments.real_training_baseline [--seeds 0 1 2]   # writes real_training_baseline.json / .md

Each seed's network is cached by the hash of its settings (``real_training_common.run_folder``) and
its test metrics beside it (``test/metrics.json``): a rerun trains and scores only what is missing,
so the seeds can span sessions.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json

import numpy as np

from experiments.real_common import HERE
from experiments.real_training_common import CAMVID, Settings, cache_folder, train_decoder

NAME = "real_training_baseline"
COMPETENT = 55.0  # % CamVid test mIoU: ESPNet's published 55.6 rounded down (ENet: 51.3)


def test_metrics(folder) -> dict:
    """``jaxanom evaluate --dataset camvid --split test`` of the run in ``folder`` (cached beside it)."""
    from jaxanom.app.commands.evaluate import segmentation

    stored = folder / "test" / "metrics.json"
    if not stored.exists():
        with contextlib.redirect_stdout(io.StringIO()):
            segmentation(run=str(folder / "run"), dataset="camvid", path=str(CAMVID), split="test",
                         out=str(folder / "test"))
    return json.loads(stored.read_text())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = parser.parse_args(argv)
    rows = []
    for seed in args.seeds:
        folder = train_decoder(Settings(seed=seed))
        result = json.loads((folder / "result.json").read_text())
        test = test_metrics(folder)
        wall = (folder / "result.json").stat().st_mtime - (folder / "settings.json").stat().st_mtime
        history = [json.loads(line) for line in (folder / "val_history.jsonl").read_text().splitlines()]
        rows.append({"seed": seed, "run": str(folder / "run"), "val_miou": result["val_miou"], "val_history": history,
                     "wall_seconds_last_session": wall, "steps_last_session": result["steps_this_session"],
                     "test_miou": test["metrics"]["miou"], "test_pixel_accuracy": test["metrics"]["pixel_accuracy"],
                     "test_iou": dict(zip(test["metrics"]["classes"], test["metrics"]["iou"])),
                     "median_step_seconds": result["median_step_seconds"], "settings": result["settings"]})
        print(f"seed {seed}: test mIoU {100 * rows[-1]['test_miou']:.2f}%, val mIoU {100 * result['val_miou']:.2f}%")
    (HERE / f"{NAME}.json").write_text(json.dumps({"rows": rows}, indent=1) + "\n")
    (HERE / f"{NAME}.md").write_text(markdown(rows))


def cache_timing(split: str, flip: bool) -> float | None:
    """Seconds per frame of the encoder pass when ``split`` (``flip``) was cached, where recorded."""
    path = cache_folder(split, flip) / "timing.json"
    return json.loads(path.read_text())["seconds_per_frame"] if path.exists() else None


def markdown(rows: list[dict]) -> str:
    """The report: each seed's CamVid test mIoU and per-class IoU, the budget, the verdict."""
    settings = rows[0]["settings"]
    crop = [8 * n for n in settings["crop"]]
    lines = [
        "# Training claims on real frames: the CamVid baseline (ERFNet, Cityscapes encoder frozen)", "",
        f"Written by `python -m experiments.{NAME}`. The ERFNet authors' Cityscapes weights (int8 redistribution, "
        "dequantised): the encoder frozen, its features cached once per frame at 360x480 (the 367 training frames "
        "and their horizontal flips), the decoder trained on them with a new 11-class head "
        f"(`experiments/real_training_common.py`): {settings['steps']} steps, batch {settings['batch_size']}, random "
        f"crops of {settings['crop'][0]}x{settings['crop'][1]} feature cells ({crop[0]}x{crop[1]} pixels), "
        f"{settings['optimizer']} lr {settings['lr']:g} with poly decay, weight decay {settings['weight_decay']:g}, "
        f"cross-entropy with ENet's class weights. No random scaling and no colour jitter (not possible on cached "
        "features). CamVid test: the 233 frames at 360x480, mIoU over the 11 classes with void ignored "
        "(`jaxanom evaluate --dataset camvid --split test`). Timings on 2 CPU cores shared with other "
        "processes (load average 8-10): costs of this session, not benchmarks.", "",
        "| seed | test mIoU % | test pixel accuracy % | val mIoU % | steps | s / step (median) | wall min (last session) |",
        "|---|---|---|---|---|---|---|"]
    for row in rows:
        step = row["median_step_seconds"]
        lines.append(f"| {row['seed']} | {100 * row['test_miou']:.2f} | {100 * row['test_pixel_accuracy']:.2f} | "
                     f"{100 * row['val_miou']:.2f} | {row['settings']['steps']} | "
                     f"{'-' if step is None else f'{step:.2f}'} | {row['wall_seconds_last_session'] / 60:.1f} |")
    names = list(rows[0]["test_iou"])
    lines += ["", "Per-class test IoU %:", "", "| seed | " + " | ".join(names) + " |",
              "|---|" + "---|" * len(names)]
    for row in rows:
        lines.append(f"| {row['seed']} | " + " | ".join(f"{100 * v:.1f}" for v in row["test_iou"].values()) + " |")
    lines += ["", "Val mIoU % along the training (cached val features, every checkpoint): " + "; ".join(
        f"seed {row['seed']}: " + ", ".join(f"{h['step']}: {100 * h['val_miou']:.1f}" for h in row["val_history"])
        for row in rows)]
    costs = {f"{split}{' flipped' if flip else ''}": cache_timing(split, flip)
             for split, flip in (("train", False), ("train", True), ("val", False), ("test", False))}
    lines += ["", "Encoder pass per frame when caching (360x480, float32, wall s): " + ", ".join(
        f"{name} {value:.2f}" for name, value in costs.items() if value is not None) + "."]
    test = np.array([100 * row["test_miou"] for row in rows])
    spread = f" (seeds: mean {test.mean():.2f}, range {test.min():.2f}-{test.max():.2f})" if len(rows) > 1 else ""
    verdict = ("competent" if test.min() >= COMPETENT else
               f"short of competent by {COMPETENT - test.min():.2f} points" if test.max() < COMPETENT else
               "competent in some seeds only")
    lines += ["", f"Verdict: test mIoU {', '.join(f'{t:.2f}' for t in test)}{spread} against the {COMPETENT:g}% "
              f"asked (published on CamVid's test frames, trained there: ENet 51.3, ESPNet 55.6): {verdict}.", "",
              "What differs from the papers: ERFNet, not DeepLabV3+ R101; CamVid (11 classes, 367 training frames), "
              "not Cityscapes; the encoder is the Cityscapes one, frozen, and only the decoder is trained (not "
              "training from ImageNet); no scale or colour augmentation.", "",
              "The training claims on this regime (CuDAM Table II and the Table III ablation, MSAAM Table 6, "
              "anomaly metrics on RoadAnomaly21 and RoadObstacle21) are the next section "
              "(`experiments/real_training_claims.py`)."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
