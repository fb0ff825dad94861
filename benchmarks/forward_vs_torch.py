"""A segmentation network's forward pass in jaxanom against its PyTorch rendering, same weights.

Shared by ``bench_espnet.py`` and ``bench_erfnet.py``: the peer is the rendering the exactness
tests check (``tests/torch_reference.py``), eval mode, no gradients; both sides float32 (on a GPU
PyTorch runs channels-last). ``wall_rows``: median wall time of each side in turn (what
``python -m benchmarks`` records). ``cpu_rows``: one thread each, the two alternating call by call
in one process, median process CPU time (``getrusage``): on a CPU shared with other work, wall
time mostly measures the other work (docs/decisions/cpu-speed.md); the caller sets XLA's
``--xla_cpu_multi_thread_eigen=false`` before JAX starts. ``ratio`` = PyTorch ms / jaxanom ms
(above 1: jaxanom is faster).
"""
from __future__ import annotations

import importlib.util
import os
import resource
import statistics
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.timing import flop_rate, median_ms

ROOT = Path(__file__).resolve().parent.parent
REALDATA = Path(os.environ.get("JAXANOM_REALDATA", ROOT.parent / "shared" / "realdata"))


def torch_reference():
    """``tests/torch_reference.py`` as a module (the PyTorch renderings); None without torch."""
    if importlib.util.find_spec("torch") is None:
        return None
    spec = importlib.util.spec_from_file_location("torch_reference", ROOT / "tests" / "torch_reference.py")
    reference = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(reference)
    return reference


def _jax_call(model, variables, shape):
    images = jnp.asarray(np.random.default_rng(0).normal(size=(*shape, 3)).astype(np.float32))
    forward = jax.jit(lambda v, x: model.apply(v, x, train=False)["logits"])
    return (lambda: jax.block_until_ready(forward(variables, images))), forward, images


def _torch_call(net, shape):
    import torch

    device = "cuda" if torch.cuda.is_available() else "cpu"
    fmt = torch.channels_last if device == "cuda" else torch.contiguous_format
    net = net.to(device, memory_format=fmt)
    x = torch.randn(shape[0], 3, *shape[1:], device=device).to(memory_format=fmt)

    def forward():
        with torch.no_grad():
            return net(x)

    return forward


def _case(label: str, shape) -> str:
    return " ".join(part for part in (label, f"{shape[0]}x{shape[2]}x{shape[1]} float32") if part)


def wall_rows(benchmark: str, label: str, model, variables, net, shapes, repeats: int, weights: str) -> list[dict]:
    """Rows of median wall ms per shape (B, H, W), jaxanom then the peer ``net`` (None: no peer)."""
    rows = []
    for shape in shapes:
        call, forward, images = _jax_call(model, variables, shape)
        ms = median_ms(call, repeats=repeats, warmup=2)
        row = {"benchmark": benchmark, "case": _case(label, shape), "impl": "jaxanom", "median_ms": ms,
               "note": f"{1e3 * shape[0] / ms:.1f} images/s; {flop_rate(forward, variables, images, ms=ms)}; {weights}"}
        rows.append(row)
        if net is not None:
            peer = median_ms(_torch_call(net, shape), repeats=repeats, warmup=2)
            row["ratio"] = peer / ms
            rows.append({"benchmark": benchmark, "case": _case(label, shape), "impl": "pytorch", "median_ms": peer,
                         "note": f"{1e3 * shape[0] / peer:.1f} images/s"})
    return rows


def _cpu_ms() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return (usage.ru_utime + usage.ru_stime) * 1e3


def cpu_rows(benchmark: str, label: str, model, variables, net, shapes, repeats: int) -> list[dict]:
    """One thread each, interleaved: rows of median process CPU ms per shape, with the load average."""
    import torch

    torch.set_num_threads(1)
    rows = []
    for shape in shapes:
        calls = {"jaxanom": _jax_call(model, variables, shape)[0], "pytorch": _torch_call(net, shape)}
        for call in calls.values():
            call()
        times = {name: [] for name in calls}
        load = [os.getloadavg()[0]]
        for _ in range(repeats):
            for name, call in calls.items():
                start = _cpu_ms()
                call()
                times[name].append(_cpu_ms() - start)
            load.append(os.getloadavg()[0])
        ms = {name: statistics.median(values) for name, values in times.items()}
        note = f"one thread, CPU time, median of {repeats}; load average {min(load):.1f}-{max(load):.1f}"
        rows += [{"benchmark": benchmark, "case": _case(label, shape), "impl": "jaxanom", "median_ms": ms["jaxanom"],
                  "ratio": ms["pytorch"] / ms["jaxanom"], "note": note},
                 {"benchmark": benchmark, "case": _case(label, shape), "impl": "pytorch", "median_ms": ms["pytorch"],
                  "note": f"spread {min(times['pytorch']):.0f}-{max(times['pytorch']):.0f} ms; jaxanom's "
                          f"{min(times['jaxanom']):.0f}-{max(times['jaxanom']):.0f} ms"}]
    return rows
