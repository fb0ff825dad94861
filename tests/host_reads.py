"""Counting device-to-host reads of jax Arrays, on every backend.

The CPU backend ignores ``jax.transfer_guard`` for ``float`` / ``bool`` / ``device_get``, so a
test that must fail on the CPU when a loop reads the device counts the reads where each of them
passes: an Array's host value (``ArrayImpl._value``, behind ``bool``, ``float``, ``int``,
``item``, ``tolist`` and ``device_get``), and NumPy's ``asarray`` / ``array`` of an Array (on the
CPU those take the buffer protocol instead).
"""
from __future__ import annotations

from typing import Callable

import jax
import numpy as np


def count_host_reads(monkeypatch, tag: Callable[[], object] = lambda: None) -> list:
    """Patch the reads (undone with ``monkeypatch``); returns the list that each read appends
    ``tag()`` to (e.g. how many batches had been dispatched when it happened)."""
    from jax._src.array import ArrayImpl

    reads: list = []
    host_value = ArrayImpl._value

    def read(self):
        reads.append(tag())
        return host_value.fget(self)

    monkeypatch.setattr(ArrayImpl, "_value", property(read))
    for name in ("asarray", "array"):
        numpy_fn = getattr(np, name)

        def counted(value, *args, _numpy_fn=numpy_fn, **kwargs):
            if isinstance(value, jax.Array):
                reads.append(tag())
            return _numpy_fn(value, *args, **kwargs)

        monkeypatch.setattr(np, name, counted)
    return reads
