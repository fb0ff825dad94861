"""The CamVid baseline of the training claims: the Cityscapes ERFNet's encoder frozen, its decoder
(new 11-class head) trained on cached features (``real_training_common``), scored on CamVid's 233
test frames by ``jaxanom evaluate --dataset camvid`` (11 classes, void ignored).

    python -m experiments.real_training_baseline [--seeds 0 1 2]   # writes real_training_baseline.json

Each seed's network is cached by the hash of its settings (``real_training_common.run_folder``) and
its test metrics beside it (``test/metrics.json``): a rerun trains and scores only what is missing,
so the seeds can span sessions. The .md beside this file is written by hand from the .json.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json

from experiments.real_common import HERE
from experiments.real_training_common import CAMVID, Settings, train_decoder

OUT = HERE / "real_training_baseline.json"


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
        rows.append({"seed": seed, "run": str(folder / "run"), "val_miou": result["val_miou"],
                     "test_miou": test["metrics"]["miou"], "test_pixel_accuracy": test["metrics"]["pixel_accuracy"],
                     "test_iou": dict(zip(test["metrics"]["classes"], test["metrics"]["iou"])),
                     "median_step_seconds": result["median_step_seconds"], "settings": result["settings"]})
        print(f"seed {seed}: test mIoU {100 * rows[-1]['test_miou']:.2f}%, val mIoU {100 * result['val_miou']:.2f}%")
    OUT.write_text(json.dumps({"rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
