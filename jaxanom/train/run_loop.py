"""The step loop every trainer runs: resume, steps, metrics read on logging steps, evaluation, checkpoints.

``run_loop(step, init, batches, steps, ...)`` applies a step ``(state, batch) -> (state, metrics)``
(``metrics``: a dict of arrays, still on the device) to ``batches`` until the state has taken
``steps`` steps, and returns that state. Step numbers count from 1. What differs between trainers
is handed in:

- ``checkpoints``: the checkpoint policy. ``None``: nothing is saved or resumed.
  ``Checkpoints(run_dir, every, keep)``: orbax checkpoints in ``run_dir/checkpoints`` every
  ``every`` steps (``None``: at the last step only) and at the last step; a folder that already
  holds one is resumed from the newest (a damaged newest one stops the run with a ValueError;
  nothing is silently restarted).
- ``on_log(logged, examples_per_s)``: what to do with the metrics of the steps since the last
  logging step, ``[(step, {name: host value}), ...]``; it may return a summary for the progress bar.
- ``evaluate(step, state)``: every ``eval_every`` steps (``None``: never) and at the last.
- ``progress(range of the step numbers still to run) -> iterable``: a wrapper such as tqdm.

The metrics stay on the device until a logging step (every ``log_every`` steps, every step that
evaluates or saves, and the last): reading them back every step would make the host wait for each
step before it dispatches the next (big_vision's loop reads them the same way). They are then read
in one transfer and checked for NaN/Inf before anything is saved: a non-finite one stops the run
with NonFiniteLossError, the last good checkpoint kept. Before each save and at the last step, the
state itself is checked too (one boolean read): finite metrics do not prove finite weights.

Resuming: when the iterator of ``batches`` has ``get_state`` / ``set_state`` (grain's
``DatasetIterator`` has them), its position is saved with each checkpoint as JSON and restored;
otherwise a resumed run skips as many batches as were already used, right for any deterministic
input. On multi-host runs the saved position is process 0's, right when every process's pipeline
advances alike (grain with one shard per process).
"""
from __future__ import annotations

import dataclasses
import itertools
import os
import time
from typing import Any, Callable, Iterable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_count
from jaxanom.train.checkpoint import Checkpointer


class NonFiniteLossError(FloatingPointError):
    """A loss or gradient norm became NaN or infinite; the run stopped before saving it."""


@dataclasses.dataclass(frozen=True)
class Checkpoints:
    """Save into ``run_dir/checkpoints`` every ``every`` steps (``None``: at the last step only) and
    at the last step, keeping the newest ``keep``; a run whose folder holds one resumes from the newest."""

    run_dir: str
    every: int | None = None
    keep: int = 3

    def __post_init__(self):
        if self.every is not None:
            check_count("every", self.every)
        check_count("keep", self.keep)

    @property
    def directory(self) -> str:
        return os.path.join(self.run_dir, "checkpoints")


def run_loop(step: Callable[[Any, Any], tuple[Any, dict]], init: Callable[..., Any], batches: Iterable, steps: int,
             *, init_args: tuple = (), first: Any = None, checkpoints: Checkpoints | None = None,
             log_every: int | None = None, on_log: Callable[[list, float | None], dict | None] | None = None,
             finite: Sequence[str] | None = None, examples: Callable[[Any], int] | None = None,
             evaluate: Callable[[int, Any], None] | None = None, eval_every: int | None = None,
             progress: Callable[[range], Iterable[int]] | None = None) -> Any:
    """Run ``step`` until the state has taken ``steps`` steps (see the module docstring); the final state.

    ``init(*init_args)``: a fresh run's state; a resumed run restores into
    ``jax.eval_shape(init, *init_args)`` (shapes, dtypes and shardings; nothing is computed), and
    then the state needs a ``step`` field (the steps it has taken). ``first``: a batch the caller
    already took from ``batches``' iterator (to check it or to shape the state); a fresh run steps
    on it first. ``log_every``: ``None`` reads the metrics at the last step (and at evaluations and
    saves) only. ``finite``: the metrics that must stay finite (``None``: all; empty: none, and
    the state is not checked either). ``examples(batch)``: its number of examples, for ``on_log``'s
    throughput (``None`` without it).
    """
    check_count("steps", steps)
    for name, value in (("log_every", log_every), ("eval_every", eval_every)):
        if value is not None:
            check_count(name, value)
    watched = finite is None or len(finite) > 0
    source = iter(batches)
    resumable = hasattr(source, "get_state") and hasattr(source, "set_state")
    pending = [] if first is None else [first]
    # every=None: due on the grid of ``steps`` itself, which a run reaches at its last step only
    checkpointer = None if checkpoints is None else Checkpointer(checkpoints.directory, checkpoints.every or steps,
                                                                 checkpoints.keep)
    numbers = None
    try:
        if checkpointer is None or checkpointer.latest_step() is None:
            state, start = init(*init_args), 0
        else:
            state, data_state = checkpointer.restore(jax.eval_shape(init, *init_args))
            start, pending = int(state.step), []
            if start > steps:
                raise ValueError(f"steps: expected at least the {start} steps the run in {checkpoints.run_dir} "
                                 f"has trained, got {steps}")
            if start < steps:  # a finished run reads no batch
                if resumable and data_state is not None:
                    _set_data_state(source, data_state)
                else:
                    for _ in range(start - (first is not None)):
                        next(source)
        inputs = itertools.chain(pending, source)
        numbers = range(start + 1, steps + 1) if progress is None else progress(range(start + 1, steps + 1))
        unread, seen, tick = [], 0, time.perf_counter()  # the steps since the last logging step
        for number in numbers:
            batch = next(inputs)
            state, metrics = step(state, batch)
            unread.append((number, metrics))
            seen += examples(batch) if examples is not None else 0
            evaluates = evaluate is not None and (number == steps or (eval_every is not None
                                                                     and number % eval_every == 0))
            saves = checkpointer is not None and (number == steps or checkpointer.is_due(number))
            if not (evaluates or saves or number == steps or (log_every is not None and number % log_every == 0)):
                continue
            logged = _read(unread, finite, checkpointer)
            summary = None if on_log is None else on_log(
                logged, seen / (time.perf_counter() - tick) if examples is not None else None)
            if summary and hasattr(numbers, "set_postfix"):
                numbers.set_postfix(summary)
            unread, seen = [], 0
            if (saves or number == steps) and watched:  # one read per save: no checkpoint, nor a finished run, of NaN
                _check_finite_state(state, number, checkpointer)
            if evaluates:
                evaluate(number, state)
            if saves:
                checkpointer.save(number, state, _data_state(source) if resumable else None)
            tick = time.perf_counter()
        if checkpointer is not None:
            checkpointer.wait()
    finally:
        if hasattr(numbers, "close"):  # a progress bar, a wrapping generator
            numbers.close()
        if checkpointer is not None:
            checkpointer.close()
    return state


def progress_bar(enabled: bool) -> Callable[[range], Iterable[int]] | None:
    """A ``progress`` for ``run_loop``: a tqdm bar that counts the steps a resumed run had taken."""
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return lambda numbers: tqdm(numbers, total=numbers.stop - 1, initial=numbers.start - 1, dynamic_ncols=True)


def _read(unread: list, finite: Sequence[str] | None, checkpointer: Checkpointer | None) -> list:
    """``[(step, host metrics)]`` of ``unread`` in one transfer; NonFiniteLossError at the first
    step with a non-finite metric among ``finite`` (all when None), after pending saves finish."""
    values = jax.device_get([metrics for _, metrics in unread])
    for (number, _), metrics in zip(unread, values):
        names = list(metrics) if finite is None else finite
        if all(np.all(np.isfinite(metrics[name])) for name in names):
            continue
        shown = ", ".join(f"{name} {metrics[name]}" for name in names)
        raise NonFiniteLossError(f"{shown} at step {number}: training stopped; {_kept(checkpointer)}")
    return [(number, metrics) for (number, _), metrics in zip(unread, values)]


@jax.jit
def _all_finite(state) -> jax.Array:
    """Whether every floating-point leaf of ``state`` is finite: one boolean, computed on the device."""
    leaves = [jnp.isfinite(x).all() for x in jax.tree.leaves(state) if jnp.issubdtype(x.dtype, jnp.inexact)]
    return jnp.stack(leaves).all() if leaves else jnp.bool_(True)


def _check_finite_state(state, number: int, checkpointer: Checkpointer | None) -> None:
    """NonFiniteLossError when ``state`` (weights, optimizer moments) holds NaN or Inf after step
    ``number``: finite metrics do not prove finite weights (a NaN clip norm scales the update, not
    the loss it was computed from)."""
    if not bool(_all_finite(state)):
        raise NonFiniteLossError(f"the weights or optimizer state hold NaN or Inf after step {number}: training "
                                 f"stopped; {_kept(checkpointer)}")


def _kept(checkpointer: Checkpointer | None) -> str:
    """What a stopped run leaves: its newest checkpoint (after pending saves finish), or that there is none."""
    if checkpointer is None:
        return "nothing was saved"
    checkpointer.wait()
    step = checkpointer.latest_step()
    return (f"no checkpoint was saved before (none in {checkpointer.directory})" if step is None
            else f"last good checkpoint: step {step} in {checkpointer.directory}")


def _data_state(batches) -> Any:
    state = batches.get_state()
    return state.decode() if isinstance(state, bytes) else state


def _set_data_state(batches, state: Any) -> None:
    batches.set_state(state.encode() if isinstance(state, str) else state)
