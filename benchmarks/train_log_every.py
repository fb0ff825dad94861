"""Training throughput with the metrics read every step against every ``--log-every`` steps, in one run.

The train loop reads its metrics (loss, gradient norm) from the device on logging steps only; this
measures what a read on every step would cost. Each measurement is a fresh process running
``jaxanom.train.segmenter.train`` for STEPS steps of a network on one random batch, repeated (no input
pipeline: the host only dispatches steps and, on logging steps, waits for the device and reads
the metrics), with one checkpoint at the end. Its images per second are read from the run's own
log (``train/images_per_s`` of each step's line: the rate of the window between two reads) over
the steps after the first ``--log-every`` steps (compiling and the first window are not counted).
The two settings alternate (1, N, 1, N, ...) so a change of the machine's load hits both.

    PYTHONPATH=. python benchmarks/train_log_every.py [--network deeplabv3plus_r50] [--size 256 512]
        [--batch 8] [--steps 300] [--log-every 50] [--rounds 3]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def measure(network: str, size: tuple[int, int], batch: int, steps: int, log_every: int, run_dir: str,
            skip: int) -> dict:
    """In this process: images/s of steps ``skip + 1 .. steps`` of a ``log_every`` training run."""
    import numpy as np

    from jaxanom.models import build_model
    from jaxanom.train.segmenter import TrainConfig, train

    rng = np.random.default_rng(0)
    data = {"image": rng.integers(0, 256, (batch, *size, 3), dtype=np.uint8),
            "label": rng.integers(0, 19, (batch, *size), dtype=np.int32)}
    config = TrainConfig(run_dir, steps=steps, log_every=log_every, save_every=steps, eval_every=steps,
                         progress=False, keep=1)
    train(config, build_model(network, num_classes=19), iter([data] * steps))
    lines = [json.loads(line) for line in (Path(run_dir) / "log.jsonl").read_text().splitlines()]
    rates = [line["train/images_per_s"] for line in lines if "train/images_per_s" in line and line["step"] > skip]
    seconds = sum(batch / rate for rate in rates)
    return {"images_per_s": len(rates) * batch / seconds, "steps_timed": len(rates)}


def _child(args: argparse.Namespace, log_every: int, run_dir: str) -> dict:
    code = (f"import sys, json; sys.path.insert(0, {str(HERE)!r}); from train_log_every import measure; "
            f"print(json.dumps(measure({args.network!r}, {tuple(args.size)!r}, {args.batch}, {args.steps}, "
            f"{log_every}, {run_dir!r}, {args.log_every})))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(
                              filter(None, (str(HERE.parent), os.environ.get("PYTHONPATH"))))})
    if done.returncode:
        raise RuntimeError(f"log_every={log_every} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--network", default="deeplabv3plus_r50")
    parser.add_argument("--size", type=int, nargs=2, default=(256, 512), metavar=("H", "W"))
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--log-every", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    if not args.steps >= 2 * args.log_every >= 2:
        parser.error(f"--steps {args.steps}: expected at least twice --log-every {args.log_every}")
    sys.path.insert(0, str(HERE.parent))
    from benchmarks.timing import environment, markdown_table

    runs: dict[int, list[float]] = {1: [], args.log_every: []}
    with tempfile.TemporaryDirectory() as folder:
        for round_ in range(args.rounds):
            for log_every in runs:
                result = _child(args, log_every, os.path.join(folder, f"run{round_}_{log_every}"))
                runs[log_every].append(result["images_per_s"])
                print(f"round {round_ + 1} log_every {log_every}: {result['images_per_s']:.2f} images/s "
                      f"over {result['steps_timed']} steps", file=sys.stderr)
    case = f"{args.network} {args.batch}x{args.size[0]}x{args.size[1]}, steps {args.log_every + 1}-{args.steps}"
    rows = [{"benchmark": "train images/s", "case": case, "impl": f"metrics read every {n} step(s)",
             "images_per_s": f"{statistics.median(values):.2f}",
             "note": "rounds: " + ", ".join(f"{v:.2f}" for v in values)} for n, values in runs.items()]
    print(environment())
    print(markdown_table(rows, ["benchmark", "case", "impl", "images_per_s", "note"]))
    print(f"every {args.log_every} / every step: "
          f"{statistics.median(runs[args.log_every]) / statistics.median(runs[1]):.3f}")


if __name__ == "__main__":
    main()
