"""Work done before the tables, in several processes: ``python -m experiments --jobs N``.

Training a network, building an MMF pipeline or computing an off-road seed fills the runs folder,
and the table that needs it afterwards only restores it. On 2 CPU cores two processes train
about 1.4x as many networks per hour as one (one XLA process does not keep both cores busy), so
``run_jobs`` runs the jobs of every selected table in a pool of spawned processes, longest first,
before the tables run one after the other. A job that fails is reported and left to its table,
which retries it and reports the failure where the table would have.
"""
from __future__ import annotations

import dataclasses
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Callable, Sequence


@dataclasses.dataclass(frozen=True)
class Job:
    """``function(*args)`` in a worker process (both picklable); ``minutes``: its rough length, for the
    order (longest first)."""

    label: str
    function: Callable
    args: tuple
    minutes: float


def end_with_parent() -> None:
    """Make this worker process end (SIGTERM) when the process that started it dies, killed included
    (Linux; nothing elsewhere): no orphan keeps computing or writing a run that a rerun rewrites.
    A pool's ``initializer``."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _worker_start(cache_dir: str, processes: int) -> None:
    """A worker ends with the process that started it, shares the runner's compilation cache and, on
    an accelerator, takes its share of the memory (JAX would preallocate 75% in each process)."""
    os.environ.setdefault("XLA_PYTHON_CLIENT_MEM_FRACTION", f"{0.8 / processes:.2f}")
    end_with_parent()
    import jax

    jax.config.update("jax_compilation_cache_dir", cache_dir)


def run_jobs(jobs: Sequence[Job], processes: int, cache_dir: Path, log: Callable = print) -> dict[str, str]:
    """Run ``jobs`` in ``processes`` spawned workers, longest first; returns ``{label: error}`` of the failed
    ones. With one process (or no job) nothing runs here: the tables do the work themselves."""
    if processes < 1:
        raise ValueError(f"processes: expected >= 1, got {processes}")
    if processes == 1 or not jobs:
        return {}
    failed, start = {}, time.perf_counter()
    log(f"{len(jobs)} jobs in {processes} processes")
    context = multiprocessing.get_context("spawn")  # a forked JAX process is unsafe
    with ProcessPoolExecutor(processes, mp_context=context, initializer=_worker_start,
                             initargs=(str(cache_dir), processes)) as pool:
        futures = {pool.submit(job.function, *job.args): job for job in sorted(jobs, key=lambda j: -j.minutes)}
        for future in as_completed(futures):
            label, error = futures[future].label, future.exception()
            if error is not None:
                failed[label] = f"{type(error).__name__}: {error}"
            log(f"job {label}: {'failed: ' + failed[label] if error else 'done'} "
                f"({(time.perf_counter() - start) / 60:.1f} min since the first job)")
    return failed
