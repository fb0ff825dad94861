"""Checkpoints: orbax's ``CheckpointManager`` behind a small API (its own API moves between versions).

A checkpoint of step t holds the full ``TrainState`` and, as JSON, the input iterator's position
after t batches (``None`` when the input cannot report one); a reader that needs the model's
variables alone reads just those fields (``restore_part``). orbax writes each step into a
temporary folder and renames it when complete, so a run killed while saving leaves the previous
checkpoints intact.
"""
from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from jaxanom._validate import in_host_memory
from jaxanom.errors import first_line


class DamagedCheckpointError(ValueError):
    """A saved step that cannot be read or holds NaN/Inf: the folder's files are at fault, not the
    code, so a command that resumes there can say so in one line."""


# orbax splits a replicated array among its replicas (each device writes a slice), which compiles
# one slice per array shape and device: 216 compiles on the first save of the MMF quick demo's
# small networks on 4 CPU devices. Below this size one replica writes the whole array.
_MIN_REPLICA_SLICE_BYTES = 1 << 20


def _handler() -> ocp.PyTreeCheckpointHandler:
    scalar = ocp.type_handlers.ScalarHandler()
    registry = ocp.type_handlers.create_type_handler_registry(
        (int, scalar), (float, scalar), (bytes, scalar), (np.number, scalar), (np.ndarray, ocp.type_handlers.NumpyHandler()),
        (jax.Array, ocp.type_handlers.ArrayHandler(min_slice_bytes_for_replica_parallel=_MIN_REPLICA_SLICE_BYTES)),
        (str, ocp.type_handlers.StringHandler()))
    return ocp.PyTreeCheckpointHandler(type_handler_registry=registry)


def _abstract(tree):
    """Shapes, dtypes and shardings to restore into; host arrays and shapes without a sharding
    (``jax.eval_shape``) go to the first local device, whatever devices the writer had (a run
    trained on many hosts is read on one)."""
    default = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    return jax.tree.map(
        lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=getattr(x, "sharding", None) or default), tree)


@jax.jit
def _all_finite(leaves: list) -> list:
    """Per leaf, whether it holds no NaN/Inf: one compiled call for a whole state."""
    return [jnp.all(jnp.isfinite(leaf)) for leaf in leaves]


def _finite(leaves: list) -> list[bool]:
    """Per leaf, whether it holds no NaN/Inf: NumPy reads the leaves in host memory (no compile),
    one compiled call checks those on accelerators where they lie."""
    on_device = [leaf for leaf in leaves if not in_host_memory(leaf)]
    device_finite = iter(jax.device_get(_all_finite(on_device)) if on_device else ())
    return [bool(np.isfinite(np.asarray(leaf)).all()) if in_host_memory(leaf) else bool(next(device_finite))
            for leaf in leaves]


@contextlib.contextmanager
def _without_read_only_notice():
    """Within the block, orbax's warning "Given directory is read only", logged for every read-only
    manager (readers open runs read-only on purpose), is dropped; its other messages pass."""
    def keep(record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Given directory is read only")

    logger = logging.getLogger("absl")
    logger.addFilter(keep)
    try:
        yield
    finally:
        logger.removeFilter(keep)


class Checkpointer:
    """Knows when a step is due (every ``save_every``), saves, keeps the last ``keep``, restores.

    ``directory`` is created if missing, and unfinished saves of an earlier, killed writer are
    removed. With ``read_only=True`` (readers of a run that may be training) nothing is created,
    removed or written: the folder may be read-only and a live writer's temporary folders survive.
    Use as a context manager, or call ``close()``: saves are asynchronous and ``close`` waits.
    """

    def __init__(self, directory: str | os.PathLike, save_every: int = 1000, keep: int = 3, *,
                 read_only: bool = False):
        if save_every < 1 or keep < 1:
            raise ValueError(f"save_every, keep: expected >= 1, got {save_every}, {keep}")
        self.directory = os.path.abspath(directory)
        self.save_every = save_every
        if read_only:  # every option a reader has no use for off, or orbax warns that it turns it off
            options = ocp.CheckpointManagerOptions(read_only=True, create=False, cleanup_tmp_directories=False,
                                                   save_interval_steps=0, max_to_keep=None)
        else:
            options = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True, cleanup_tmp_directories=True)
        with _without_read_only_notice():
            self._manager = ocp.CheckpointManager(self.directory, options=options, item_handlers={
                "state": _handler(), "data": ocp.JsonCheckpointHandler()})

    def latest_step(self) -> int | None:
        """The newest complete checkpoint's step, or None."""
        return self._manager.latest_step()

    def is_due(self, step: int) -> bool:
        """Whether ``step`` is on the ``save_every`` grid."""
        return step % self.save_every == 0

    def save(self, step: int, state: Any, data_state: Any = None) -> None:
        """Save ``state`` (a pytree of arrays) and ``data_state`` (JSON-able) as step ``step``.

        The arrays are copied to host before it returns, so ``state`` may be donated to the next
        step; the files are written in the background.
        """
        check_space(self.directory, state, f"checkpoint of step {step}")
        args = ocp.args.Composite(state=ocp.args.PyTreeSave(state),
                                  data=ocp.args.JsonSave({"iterator": data_state}))
        self._manager.save(step, args=args, force=True)

    def restore(self, template: Any, step: int | None = None) -> tuple[Any, Any]:
        """``(state, data_state)`` of ``step`` (default: the latest), shaped and sharded like ``template``.

        Raises ValueError naming the folder when there is no checkpoint, DamagedCheckpointError
        when it cannot be read or its floating-point arrays hold NaN/Inf (damaged files; training
        never saves those, see docs/decisions/reliability.md).
        """
        restored = self._restore(template, step, partial=False)
        return restored["state"], restored["data"]["iterator"]

    def restore_part(self, template: dict, step: int | None = None) -> dict:
        """Only the fields of the saved state that ``template`` names (a dict, e.g. ``{"params",
        "batch_stats", "step"}`` shaped as they were saved), read without the rest of the state
        (optimizer and objective state) and without the input position: what inference needs.
        The errors of ``restore``."""
        return self._restore(template, step, partial=True)["state"]

    def _restore(self, template: Any, step: int | None, partial: bool) -> dict:
        step = self.latest_step() if step is None else step
        if step is None:
            raise ValueError(f"checkpoint directory {self.directory}: expected at least one saved step, found none")
        abstract = _abstract(template)
        state = ocp.args.PyTreeRestore(abstract, ocp.checkpoint_utils.construct_restore_args(abstract),
                                       partial_restore=partial)
        args = ocp.args.Composite(state=state) if partial else ocp.args.Composite(state=state, data=ocp.args.JsonRestore())
        try:
            restored = self._manager.restore(step, args=args)
        except Exception as error:  # orbax raises many types for damaged files; name the step instead
            raise DamagedCheckpointError(self._damaged(step, f"cannot be read ({type(error).__name__}: "
                                                 f"{first_line(error)})")) from error
        leaves = [(path, leaf) for path, leaf in jax.tree_util.tree_leaves_with_path(restored["state"])
                  if jnp.issubdtype(leaf.dtype, jnp.inexact)]
        bad = [jax.tree_util.keystr(path) for (path, _), ok in zip(leaves, _finite([leaf for _, leaf in leaves]))
               if not ok]
        if bad:
            raise DamagedCheckpointError(self._damaged(step, f"holds NaN/Inf in {len(bad)} array(s), e.g. {bad[0]}"))
        return restored

    def _damaged(self, step: int, problem: str) -> str:
        return (f"checkpoint directory {self.directory}: step {step} {problem}; delete that step's folder "
                f"to fall back to an earlier one")

    def wait(self) -> None:
        """Block until pending asynchronous saves are on disk."""
        self._manager.wait_until_finished()

    def close(self) -> None:
        self._manager.close()

    def __enter__(self) -> "Checkpointer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def check_space(directory: str | os.PathLike, state: Any, what: str) -> None:
    """OSError(ENOSPC) naming ``what`` when the disk of ``directory`` (or of its nearest existing
    parent) has less room than ``state``'s arrays take; saving then would fail half-way, in orbax's
    background threads, with pages of tracebacks."""
    needed = sum(int(getattr(leaf, "nbytes", 0)) for leaf in jax.tree.leaves(state))
    where = os.path.abspath(directory)
    while not os.path.isdir(where) and os.path.dirname(where) != where:
        where = os.path.dirname(where)
    free = shutil.disk_usage(where).free
    if free < needed:
        raise OSError(errno.ENOSPC, f"{what} needs {needed / 2**20:.1f} MiB, the disk holds {free / 2**20:.1f} "
                      "MiB free", os.fspath(directory))


def restore_checkpoint(directory: str | os.PathLike, template: Any, step: int | None = None, *,
                       part: bool = False) -> Any:
    """Restore from an existing checkpoint folder: ``(state, data_state)``, or with ``part`` the saved
    state's fields that the dict ``template`` names (``Checkpointer.restore_part``); ValueError if the
    folder is missing, empty or damaged."""
    if not os.path.isdir(directory):
        raise ValueError(f"checkpoint directory: expected an existing folder, got {os.fspath(directory)!r}")
    with Checkpointer(directory, read_only=True) as checkpointer:
        return checkpointer.restore_part(template, step) if part else checkpointer.restore(template, step)
