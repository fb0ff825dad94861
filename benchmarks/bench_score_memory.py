"""Peak memory of ``jaxanom score`` against the size of its logits file.

Each case writes float16 NCHW logits of 19 classes at 256 x 512 (about 5 MB an image), labels
and SML statistics, then runs ``jaxanom score`` with its default methods (msp, max_logit,
entropy, energy, sml, sml_post) in a fresh process; peak_mb is that process's peak resident
memory (``VmHWM`` of ``/proc/self/status``, read at exit), which includes the Python/JAX runtime
and the memory-mapped pages of the input it touched. Not ``ru_maxrss``: on Linux a child's
``ru_maxrss`` starts from its parent's resident size at the fork, so inside ``python -m
benchmarks`` (after the other benchmarks grew the parent) it measured the parent. The ``import only`` row is the runtime alone. The
bound it is held to: peak below input size + 900 MB. Run:
``PYTHONPATH=. python benchmarks/bench_score_memory.py [--quick]``.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.timing import environment, markdown_table

ROOT = Path(__file__).resolve().parents[1]
CLASSES, HEIGHT, WIDTH = 19, 256, 512
_CLI = "import sys; from jaxanom.cli import main; sys.exit(main())"


# Prepended to a child's code: at exit, write its own peak resident memory (KiB) to a file.
_REPORT_PEAK = (
    "import atexit, os\n"
    "def _report_peak():\n"
    "    lines = open('/proc/self/status').read().splitlines()\n"
    "    kib = next(line for line in lines if line.startswith('VmHWM:')).split()[1]\n"
    "    open(os.environ['JAXANOM_PEAK_FILE'], 'w').write(kib)\n"
    "atexit.register(_report_peak)\n"
)


def _peak_of(code: str, args: list[str] = ()) -> tuple[float, float]:
    """``(peak resident MiB, wall seconds)`` of ``python -c code args`` run to completion in a fresh process."""
    with tempfile.TemporaryDirectory() as folder:
        peak_file = Path(folder) / "peak"
        start = time.perf_counter()
        process = subprocess.run([sys.executable, "-c", _REPORT_PEAK + code, *args], cwd=ROOT,
                                 env={**os.environ, "JAXANOM_PEAK_FILE": str(peak_file)},
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        seconds = time.perf_counter() - start
        if process.returncode != 0:
            raise RuntimeError(f"{list(args)} failed: {process.stderr.decode()[-500:]}")
        return int(peak_file.read_text()) / 1024, seconds


def _inputs(folder: Path, images: int, seed: int = 0) -> Path:
    """Logits (written image by image, so this process stays small), labels and statistics."""
    from jaxanom.io import NpyWriter

    rng = np.random.default_rng(seed)
    with NpyWriter(folder / "logits.npy", (images, CLASSES, HEIGHT, WIDTH), np.float16) as writer:
        for _ in range(images):
            writer.write(rng.normal(size=(CLASSES, HEIGHT, WIDTH)).astype(np.float16) * 4)
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(images, HEIGHT, WIDTH), p=[0.8, 0.1, 0.1])
    np.save(folder / "labels.npy", labels)
    np.savez(folder / "stats.npz", mean=np.full(CLASSES, 6.0, np.float32), std=np.full(CLASSES, 1.5, np.float32),
             counts=np.full(CLASSES, 1000, np.int64))
    return folder / "logits.npy"


def run(quick: bool = False) -> list[dict]:
    image_mb = CLASSES * HEIGHT * WIDTH * 2 / 2**20
    sizes_mb = (20,) if quick else (50, 200)
    rows = []
    peak, seconds = _peak_of("import jax, jaxanom.cli, jaxanom.app.scoring; jaxanom.app.scoring.names(); jax.numpy.zeros(1)")
    rows.append({"benchmark": "score peak memory", "case": "import only", "impl": "python + jax + jaxanom",
                 "input_mb": 0.0, "peak_mb": peak, "peak_minus_input_mb": peak, "seconds": seconds})
    for size in sizes_mb:
        images = max(1, round(size / image_mb))
        with tempfile.TemporaryDirectory() as folder:
            folder = Path(folder)
            logits = _inputs(folder, images)
            input_mb = logits.stat().st_size / 2**20
            peak, seconds = _peak_of(_CLI, ["score", "--logits", str(logits), "--labels", str(folder / "labels.npy"),
                                            "--stats", str(folder / "stats.npz"), "--out", str(folder / "out")])
        rows.append({"benchmark": "score peak memory", "case": f"{images} images, {input_mb:.0f} MB float16",
                     "impl": "jaxanom score", "input_mb": input_mb, "peak_mb": peak,
                     "peak_minus_input_mb": peak - input_mb, "seconds": seconds})
    return rows


def interpret(rows: list[dict]) -> str:
    """One line: the largest case's peak against its bound (input + 900 MB)."""
    largest = max(rows, key=lambda r: r["input_mb"])
    verdict = "within" if largest["peak_mb"] < largest["input_mb"] + 900 else "ABOVE"
    return (f"{largest['input_mb']:.0f} MB of logits peak at {largest['peak_mb']:.0f} MB, {verdict} the bound "
            f"input + 900 MB; the runtime alone takes {rows[0]['peak_mb']:.0f} MB.")


if __name__ == "__main__":
    print(environment())
    results = run(quick="--quick" in sys.argv)
    print(markdown_table(results, ["benchmark", "case", "impl", "input_mb", "peak_mb", "peak_minus_input_mb",
                                   "seconds"]))
    print(interpret(results))
