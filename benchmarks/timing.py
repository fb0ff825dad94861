"""Shared timing and environment helpers for every benchmark script.

A benchmark row is a dict: ``{"benchmark", "case", "impl", "median_ms", ...}``; extra keys
(``peak_mb``, ``pixels``, ``note``) are allowed. ``markdown_table`` prints rows as a table.
"""
from __future__ import annotations

import platform
import statistics
import time
from typing import Any, Callable, Iterable


def _block(result: Any) -> Any:
    """Wait for asynchronous JAX / CUDA work in ``result`` to finish."""
    if type(result).__module__.startswith("torch"):
        import torch

        if result.is_cuda:
            torch.cuda.synchronize()
        return result
    import jax

    return jax.block_until_ready(result)


class Unavailable(Exception):
    """A benchmark that cannot run on this machine (a library it measures is missing): reported, not failed."""


def require(module: str) -> None:
    """Raise ``Unavailable`` unless ``module`` can be imported."""
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise Unavailable(f"not run: {module} is not installed on this machine")


def torch_device() -> str:
    """Where the PyTorch peer runs: ``"cuda"`` when PyTorch sees a GPU, else ``"cpu"``."""
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def median_ms(fn: Callable[[], Any], *, repeats: int = 7, warmup: int = 2) -> float:
    """Median wall time of ``fn()`` in milliseconds, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        _block(fn())
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        _block(fn())
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def gb_per_s(nbytes: int, ms: float) -> str:
    """Bytes moved per second, as text: the figure to hold against the device's memory bandwidth."""
    return f"{nbytes / ms / 1e6:.0f} GB/s"


def flop_rate(jitted: Callable, *args: Any, ms: float) -> str:
    """XLA's FLOP count of ``jitted(*args)`` over ``ms``, as text: to hold against the device's peak."""
    cost = jitted.lower(*args).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    flops = (cost or {}).get("flops", 0.0)
    if flops <= 0:
        return "no FLOP count"
    gflops = flops / ms / 1e6
    return f"{gflops / 1e3:.3g} TFLOP/s (XLA's count)" if gflops >= 1e3 else f"{gflops:.3g} GFLOP/s (XLA's count)"


def same_as_cpu(fn: Callable[[], Any], result: Any) -> str:
    """On an accelerator, ``fn()`` run on the CPU compared with ``result``, as a note ("" on a CPU)."""
    import jax
    import numpy as np

    if jax.default_backend() == "cpu":
        return ""
    with jax.default_device(jax.devices("cpu")[0]):
        on_cpu = np.asarray(fn())
    return f"; max |diff| to the CPU result {float(np.max(np.abs(on_cpu - np.asarray(result)))):.1e}"


def environment() -> dict[str, str]:
    """Device and library versions, for the header of a results table."""
    import jax

    env = {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "device": f"{jax.devices()[0].platform}: {jax.devices()[0].device_kind}",
        "cpu": platform.processor() or platform.machine(),
    }
    for name in ("flax", "numpy", "sklearn", "torch"):
        try:
            env[name] = __import__(name).__version__
        except ImportError:
            pass
    return env


def markdown_table(rows: Iterable[dict], columns: list[str] | None = None) -> str:
    """Rows (dicts) as a markdown table; columns default to the keys of the first row."""
    rows = list(rows)
    if not rows:
        return ""
    columns = columns or list(rows[0])
    fmt = lambda v: f"{v:.3g}" if isinstance(v, float) else str(v).replace("|", "\\|")  # noqa: E731
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines)
