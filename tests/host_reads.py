"""Counting device-to-host reads of jax Arrays, for tests that guard against them.

The CPU backend ignores ``jax.transfer_guard`` for ``float`` / ``bool`` / ``device_get``, so the
reads are counted where every one of them passes: an Array's host value (``_value``), and NumPy's
``asarray`` / ``array`` of an Array (on the CPU those use the buffer protocol instead).
"""
from __future__ import annotations

import jax
import numpy as np


def count_host_reads(monkeypatch, tag) -> list:
    """From now on (until ``monkeypatch`` undoes it), each read appends ``tag()`` to the returned list."""
    from jax._src.array import ArrayImpl

    reads = []
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
