"""``jaxanom predict`` end to end: real frames in, SML + post-processing maps out, images per second.

The converted ESPNet (the authors' Cityscapes weights from the real-data folder, ``JAXANOM_REALDATA``) scores the
RoadAnomaly21 frames (1280x720 PNG) with ``sml_post`` (statistics fitted on 2 Cityscapes frames),
writing float16 ``.npy`` maps. Two ``predict`` calls over the same frames into fresh folders
(decode, forward, SML with boundary suppression and dilated smoothing, resize back, atomic writes):
the first as a new process meets it (compiling included), the second with what the process has
compiled (the steady rate). Beside it, the network's forward pass alone at the same size: the
rest of the per-frame time is scoring, decoding and writing. No peer: PyTorch has no such
command; the ESPNet forward against PyTorch is ``bench_espnet``.

    PYTHONPATH=. python benchmarks/bench_predict.py [--quick]
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import time
from pathlib import Path

import jax.numpy as jnp

from benchmarks.timing import Unavailable, environment, markdown_table, median_ms, require

ROOT = Path(__file__).resolve().parent.parent
REALDATA = Path(os.environ.get("JAXANOM_REALDATA", ROOT.parent / "shared" / "realdata"))


def _seconds(args: list[str]) -> float:
    from jaxanom.cli import main

    start = time.perf_counter()
    with contextlib.redirect_stderr(io.StringIO()):
        code = main(args)
    if code:
        raise RuntimeError(f"jaxanom {' '.join(args)} exited {code}")
    return time.perf_counter() - start


def run(quick: bool = False) -> list[dict]:
    checkpoint = REALDATA / "espnet" / "espnet_p_2_q_8.pth"
    images = sorted((REALDATA / "RoadAnomaly21" / "images").glob("*.png"))
    if not checkpoint.is_file() or len(images) < 3 or not (REALDATA / "cityscapes8").is_dir():
        raise Unavailable(f"needs the ESPNet checkpoint, cityscapes8 and RoadAnomaly21 frames under {REALDATA}")
    require("grain")  # fit-stats reads the Cityscapes frames through the data pipeline
    images = images[:3] if quick else images
    with tempfile.TemporaryDirectory() as folder:
        run_dir, stats, out = Path(folder) / "espnet", Path(folder) / "stats.npz", Path(folder) / "out"
        _seconds(["convert-weights", "--from", "espnet-cityscapes", str(checkpoint), str(run_dir)])
        _seconds(["fit-stats", "--run", str(run_dir), "--cityscapes", str(REALDATA / "cityscapes8"), "--frames", "2",
                  "--size", "512x1024", "--out", str(stats)])
        common = ["predict", "--run", str(run_dir), "--stats", str(stats), "--methods", "sml_post", "--format", "npy",
                  "--no-progress"]
        paths = [str(p) for p in images]
        cold = _seconds(common + ["--out", str(out / "cold")] + paths)  # a fresh process: compiling included
        warm = _seconds(common + ["--out", str(out / "warm")] + paths)  # the same call again in this process
        per_frame = warm / len(images)

        from jaxanom.app.evaluate import predictor
        from jaxanom.app.experiment import build_network, load_variables

        experiment, variables = load_variables(run_dir)
        forward = predictor(build_network(experiment), variables)
        batch = jnp.zeros((1, 720, 1280, 3), jnp.uint8)
        forward_ms = median_ms(lambda: forward(batch)["logits"], repeats=3, warmup=1)
    case = f"ESPNet, sml_post, {len(images)} RoadAnomaly21 frames 1280x720, npy"
    return [{"benchmark": "predict end to end", "case": case, "impl": "jaxanom", "median_ms": 1e3 * per_frame,
             "note": f"{1 / per_frame:.2f} images/s on a second call ({warm:.1f} s); first call "
                     f"{cold:.1f} s ({len(images) / cold:.2f} images/s, compiling included)"},
            {"benchmark": "predict end to end", "case": "ESPNet forward alone, 1x720x1280", "impl": "jaxanom",
             "median_ms": forward_ms, "note": f"{100 * forward_ms / (1e3 * per_frame):.0f}% of a frame's time"}]


if __name__ == "__main__":
    print(environment())
    rows = run(quick="--quick" in sys.argv)
    print(markdown_table(rows, ["benchmark", "case", "impl", "median_ms", "note"]))
