"""``predict``'s images per second with this tree's jaxanom against another tree's, in one run.

Meant for a change's before and after: ``--before`` is a checkout of the commit before it (a
temporary ``git worktree``). Each measurement is a fresh process that imports jaxanom from one
tree and scores the same FRAMES random PNG frames (256x512 unless ``--size``) with ESPNet (p=2, q=8, 20 outputs;
weights drawn by NumPy, which the speed does not depend on) through ``app.predict.predict_images``
with seven methods that read the logits (``METHODS``; SML statistics from NumPy): decode, forward,
scores, resize back, float16 ``.npy`` writes. Two frames are scored first, so compiling is not
timed. The trees alternate (before, after, before, ...), so a change of the machine's load hits
both; a row gives the median of the rounds and every round's figure, and the load average
before and after the run. Not a ``bench_*`` module (``python -m benchmarks`` has one tree).

    PYTHONPATH=. python benchmarks/predict_before_after.py --before PATH [--frames 24] [--rounds 3] [--size H W]
        [--threads N]

``--threads`` sets ``PredictSettings.threads`` in the trees that have it (a tree before the
knob runs its one loop); without it, each tree's default.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SIZE = (256, 512)
NETWORK, CLASSES = "espnet_p2_q8", 20
METHODS = ("msp", "max_logit", "entropy", "energy", "softmax_distance", "sml", "void")


def measure(frames: Path, out: Path, size: tuple[int, int] = SIZE, threads: int | None = None) -> dict:
    """In a process whose ``jaxanom`` is the tree's: images per second of ``predict_images`` over ``frames``."""
    import numpy as np

    import jaxanom
    from jaxanom.app.evaluate import predictor
    from jaxanom.app.predict import PredictSettings, Scorer, predict_images
    from jaxanom.models import build_model

    sys.path.insert(0, str(HERE.parent / "tests"))  # the tests' NumPy-drawn weights: no init to compile
    from tiny_models import random_variables

    model = build_model(NETWORK, num_classes=CLASSES)
    variables = random_variables(0, functools.partial(model.init, train=False), np.zeros((1, *size, 3), np.float32))
    rng = np.random.default_rng(0)
    stats = (rng.normal(size=CLASSES).astype(np.float32), rng.uniform(0.5, 2, CLASSES).astype(np.float32))
    knobs = {"threads": threads} if threads and "threads" in {f.name for f in dataclasses.fields(PredictSettings)} else {}
    scorer = Scorer(predictor(model, variables), PredictSettings(METHODS, **knobs), stats)
    paths = sorted(frames.glob("*.png"))
    predict_images(paths[:2], out / "warm", scorer, progress=False)  # compiling, not timed
    start = time.perf_counter()
    predict_images(paths, out / "timed", scorer, progress=False)
    seconds = time.perf_counter() - start
    return {"images_per_s": len(paths) / seconds, "seconds": seconds, "jaxanom": jaxanom.__file__,
            "threads": knobs.get("threads", "default")}


def _child(tree: Path, frames: Path, out: Path, size: tuple[int, int], threads: int | None) -> dict:
    code = (f"import sys, json; sys.path.insert(0, {str(tree)!r}); sys.path.insert(1, {str(HERE)!r}); "
            f"from predict_before_after import measure; from pathlib import Path; "
            f"print(json.dumps(measure(Path({str(frames)!r}), Path({str(out)!r}), {tuple(size)!r}, {threads!r})))")
    done = subprocess.run([sys.executable, "-c", code], cwd=tree, capture_output=True, text=True, check=False,
                          env={**os.environ, "PYTHONPATH": str(tree)})
    if done.returncode:
        raise RuntimeError(f"measuring {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, required=True, help="a checkout of the commit before the change")
    parser.add_argument("--after", type=Path, default=HERE.parent, help="default: this tree")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--size", type=int, nargs=2, default=SIZE, metavar=("H", "W"), help="frame size (default 256 512)")
    parser.add_argument("--threads", type=int, help="PredictSettings.threads where a tree has it (default: its default)")
    args = parser.parse_args()
    import cv2
    import numpy as np

    from benchmarks.timing import environment, markdown_table

    trees = {"before": args.before.resolve(), "after": args.after.resolve()}
    runs: dict[str, list[float]] = {name: [] for name in trees}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as folder:
        frames = Path(folder) / "frames"
        frames.mkdir()
        rng = np.random.default_rng(0)
        for index in range(args.frames):
            cv2.imwrite(str(frames / f"frame{index:03d}.png"), rng.integers(0, 256, (*args.size, 3), dtype=np.uint8))
        for round_ in range(args.rounds):
            for name, tree in trees.items():
                result = _child(tree, frames, Path(folder) / f"{name}{round_}", args.size, args.threads)
                runs[name].append(result["images_per_s"])
                print(f"round {round_ + 1} {name}: {result['images_per_s']:.2f} images/s, threads "
                      f"{result['threads']} ({result['jaxanom']})",
                      file=sys.stderr)
    load_after = os.getloadavg()
    threads = "" if args.threads is None else f", threads {args.threads} where known"
    case = f"{NETWORK} {args.size[0]}x{args.size[1]}, {args.frames} PNG frames, {len(METHODS)} methods, npy{threads}"
    rows = [{"benchmark": "predict images/s", "case": case, "impl": f"{name} ({trees[name]})",
             "images_per_s": f"{statistics.median(values):.2f}",
             "note": "rounds: " + ", ".join(f"{v:.2f}" for v in values)} for name, values in runs.items()]
    print(environment())
    print(f"load average (1, 5, 15 min): before the run {load_before}, after {load_after}")
    print(markdown_table(rows, ["benchmark", "case", "impl", "images_per_s", "note"]))
    print(f"after / before: {statistics.median(runs['after']) / statistics.median(runs['before']):.3f}")


if __name__ == "__main__":
    main()
