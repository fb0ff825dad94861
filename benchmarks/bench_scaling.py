"""Scaling of jaxanom's hot paths: SML post-processing vs image size and vs batch, anomaly metrics
vs pixel count, and the data-parallel train step vs device count.

The device-count rows run one subprocess per count with ``jax_num_cpu_devices`` simulated CPU
devices (on a GPU machine too: the point is the partitioned program, not the accelerator). They
time the tiny DeepLabV3+ with CuDAM through ``jaxanom.train.step.make_steps`` on a fixed global
batch (strong scaling). Simulated devices share the machine's cores, so on a small CPU these
rows measure the cost of partitioning and the gradient all-reduce, not a speed-up.

    PYTHONPATH=. python benchmarks/bench_scaling.py [--quick]
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.timing import environment, markdown_table, median_ms

SML_SIZES = "SML vs image size"
SML_BATCH = "SML vs batch"
METRICS = "metrics vs pixels"
DEVICES = "train step vs devices"
ROOT = Path(__file__).resolve().parent.parent


def _sml_rows(quick: bool) -> list[dict]:
    import jax

    from benchmarks.bench_sml import NUM_CLASSES, make_logits
    from jaxanom import sml

    rng = np.random.default_rng(1)
    mean = rng.normal(size=NUM_CLASSES).astype(np.float32) + 5
    std = (0.5 + rng.random(NUM_CLASSES)).astype(np.float32)
    sizes = ((128, 256), (256, 512)) if quick else ((128, 256), (256, 512), (512, 1024), (1024, 2048))
    batches = (1, 2) if quick else (1, 2, 4, 8)
    cases = [(SML_SIZES, 1, h, w) for h, w in sizes] + [(SML_BATCH, b, 256, 512) for b in batches]
    rows = []
    for benchmark, batch, height, width in cases:
        logits = jax.device_put(make_logits(batch, height, width))
        ms = median_ms(lambda: sml.sml_score_batch(logits, mean, std), repeats=3 if quick else 5, warmup=1)
        mpx = batch * height * width / 1e6
        rows.append({"benchmark": benchmark, "case": f"{batch}x{height}x{width}x{NUM_CLASSES}", "impl": "jaxanom",
                     "median_ms": ms, "megapixels": mpx, "ms_per_megapixel": ms / mpx})
    return rows


def _metrics_rows(quick: bool) -> list[dict]:
    import jax

    from benchmarks.bench_metrics import jaxanom_metrics, make_data

    rows = []
    for pixels in (100_000, 1_000_000) if quick else (100_000, 1_000_000, 10_000_000, 20_000_000):
        scores, labels = (jax.device_put(x) for x in make_data(pixels))
        ms = median_ms(lambda: jaxanom_metrics(scores, labels), repeats=3, warmup=1)
        rows.append({"benchmark": METRICS, "case": f"{pixels / 1e6:g}M px", "impl": "jaxanom", "median_ms": ms,
                     "megapixels": pixels / 1e6, "ns_per_pixel": ms * 1e6 / pixels})
    return rows


def _train_step_child(devices: int, quick: bool) -> dict:
    """Time one train step on ``devices`` simulated devices (run in a fresh process)."""
    import jax

    jax.config.update("jax_num_cpu_devices", devices)
    jax.config.update("jax_platforms", "cpu")
    from jaxanom.data.synthetic import generate
    from jaxanom.models import build_model
    from jaxanom.train.optim import OptimConfig, make_optimizer
    from jaxanom.train.sharding import global_batch, make_mesh, replicated
    from jaxanom.train.state import TrainState
    from jaxanom.cudam.objective import CuDAM
    from jaxanom.train.step import make_steps, model_input

    batch, height, width = (4, 64, 128) if quick else (8, 128, 256)
    frames = [generate("train", i, 0, height=height, width=width) for i in range(batch)]
    local = {"image": np.stack([f["image"] for f in frames]),
             "label": np.stack([f["label"] for f in frames]).astype(np.int32)}
    model = build_model("deeplabv3plus_tiny", attention="cudam")
    mesh = make_mesh()
    if mesh.devices.size != devices:
        raise RuntimeError(f"expected a mesh of {devices} simulated devices, got {mesh.devices.size}")
    tx, _ = make_optimizer(OptimConfig(name="adamw", lr=1e-3), 1000)
    with jax.set_mesh(mesh):
        variables = jax.jit(model.init, static_argnames="train", out_shardings=replicated(mesh))(
            jax.random.key(0), model_input(local["image"][:1]), train=False)
        state = [jax.device_put(TrainState.create(variables, tx, jax.random.key(1)), replicated(mesh))]
        train_step, _ = make_steps(model, tx, CuDAM(tau=5e4), mesh)
        data = global_batch(local, mesh)

        def step():
            state[0], metrics = train_step(state[0], data)
            return metrics

        ms = median_ms(step, repeats=3 if quick else 7, warmup=2)
    return {"benchmark": DEVICES, "case": f"{devices} device(s), global batch {batch}x{height}x{width}",
            "impl": "jaxanom", "median_ms": ms, "devices": devices, "images_per_s": batch * 1e3 / ms}


def _train_step_rows(quick: bool) -> list[dict]:
    rows = []
    for devices in (1, 2) if quick else (1, 2, 4, 8):
        command = [sys.executable, "-m", "benchmarks.bench_scaling", "--train-step-child", str(devices)]
        if quick:
            command.append("--quick")
        env = dict(os.environ, JAX_PLATFORMS="cpu")
        done = subprocess.run(command, env=env, cwd=ROOT, capture_output=True, text=True, check=False)
        if done.returncode:
            raise RuntimeError(f"train step on {devices} simulated devices failed:\n{done.stderr[-2000:]}")
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    base = rows[0]["median_ms"]
    for row in rows:
        row["time_vs_1_device"] = row["median_ms"] / base
    return rows


def run(quick: bool = False) -> list[dict]:
    return _sml_rows(quick) + _metrics_rows(quick) + _train_step_rows(quick)


def interpret(rows: list[dict]) -> str:
    """One line: how time grows from the first case to the last."""
    first, last = rows[0], rows[-1]
    time = last["median_ms"] / first["median_ms"]
    if first["benchmark"] == DEVICES:
        return (f"{last['devices']} simulated devices take {time:.2g}x the 1-device time for the same global batch "
                f"(the devices share {os.cpu_count()} cores: partitioning overhead, not speed-up).")
    work = last["megapixels"] / first["megapixels"]
    growth = ("sub-linear: fixed per-call costs weigh on the small cases" if time < 0.9 * work
              else "super-linear" if time > 1.1 * work else "about linear")
    return f"{work:.3g}x the pixels take {time:.3g}x the time ({growth})."


if __name__ == "__main__":
    if "--train-step-child" in sys.argv:
        devices = int(sys.argv[sys.argv.index("--train-step-child") + 1])
        print(json.dumps(_train_step_child(devices, quick="--quick" in sys.argv)))
    else:
        print(environment())
        for benchmark_rows in (_sml_rows, _metrics_rows, _train_step_rows):
            rows = benchmark_rows(quick="--quick" in sys.argv)
            print(markdown_table(rows))
            print(interpret(rows))
