"""Where a run's scalars go: a JSON-lines file and TensorBoard event files in the run folder.

``log.jsonl`` gets one object per call, ``{"step": t, "time": unix seconds, name: value, ...}``;
a resumed run appends, so steps after the last checkpoint may appear twice (the later line is
the resumed run's). tensorboardX is imported only when a RunLog first writes.
"""
from __future__ import annotations

import json
import os
import time


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

            self._jsonl = open(os.path.join(self.run_dir, "log.jsonl"), "a", encoding="utf-8")
            self._tensorboard = SummaryWriter(os.path.join(self.run_dir, "tensorboard"))
        self._jsonl.write(json.dumps({"step": step, "time": time.time(), **values}) + "\n")
        self._jsonl.flush()
        for name, value in values.items():
            self._tensorboard.add_scalar(name, value, step)

    def close(self) -> None:
        if self._jsonl is not None:
            self._jsonl.close()
            self._tensorboard.close()
