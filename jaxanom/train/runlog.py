"""Where a run's scalars go: a JSON-lines file and TensorBoard event files in the run folder.

``log.jsonl`` gets one object per call, ``{"step": t, "time": unix seconds, name: value, ...}``.
A resumed run continues a run killed after its last checkpoint: the steps that run logged past
the checkpoint are repeated, so the first write of a ``RunLog`` first drops the lines at or after
the step it writes (the file rewritten under a temporary name and renamed: a kill meanwhile
leaves the old file or the new one), and the log equals an uninterrupted run's. TensorBoard's
event files are append-only: a resumed run's writer starts with a purge event at its first step
(tensorboardX's ``purge_step``), on which TensorBoard hides the older files' events at or after
that step. tensorboardX is imported only when a RunLog first writes.
"""
from __future__ import annotations

import json
import os
import time

from jaxanom.io import write_bytes_atomic

LOG = "log.jsonl"


class RunLog:
    """Scalars of one run; ``enabled=False`` (non-zero processes of a multi-host run) writes nothing.
    The files are opened by the first ``scalars``: a run refused before its first step leaves none."""

    def __init__(self, run_dir: str | os.PathLike, enabled: bool = True):
        self.run_dir = run_dir
        self.enabled = enabled
        self._jsonl = self._tensorboard = None

    def scalars(self, step: int, values: dict[str, float]) -> None:
        """Record ``values`` (name -> float) at ``step``."""
        if not self.enabled:
            return
        if self._jsonl is None:
            from tensorboardX import SummaryWriter

            resumed = keep_before(os.path.join(self.run_dir, LOG), step)
            self._jsonl = open(os.path.join(self.run_dir, LOG), "a", encoding="utf-8")
            self._tensorboard = SummaryWriter(os.path.join(self.run_dir, "tensorboard"),
                                              purge_step=step if resumed else None)
        self._jsonl.write(json.dumps({"step": step, "time": time.time(), **values}) + "\n")
        self._jsonl.flush()
        for name, value in values.items():
            self._tensorboard.add_scalar(name, value, step)

    def close(self) -> None:
        if self._jsonl is not None:
            self._jsonl.close()
            self._tensorboard.close()


def keep_before(path: str, step: int) -> bool:
    """Keep the lines of the log ``path`` whose step is below ``step`` (and drop a line cut short by a
    kill), rewriting it atomically when any goes; whether the file existed (a resumed run's)."""
    if not os.path.isfile(path):
        return False
    with open(path, encoding="utf-8") as f:
        lines = f.read().splitlines(keepends=True)
    kept = [line for line in lines if line.endswith("\n") and (logged := _step(line)) is not None and logged < step]
    if len(kept) != len(lines):
        write_bytes_atomic(path, "".join(kept).encode())
    return True


def _step(line: str) -> int | None:
    """The step of one log line, None for a line that is not a logged object (cut short)."""
    try:
        record = json.loads(line)
    except ValueError:
        return None
    return record.get("step") if isinstance(record, dict) and isinstance(record.get("step"), int) else None
