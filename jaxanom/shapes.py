"""Array sizes rounded up to a few per doubling, so that data of nearby sizes share one compile."""
from __future__ import annotations


def padded_size(count: int, per_doubling: int = 4, min_step: int = 16) -> int:
    """``count`` rounded up to a multiple of ``step``: the octave's width over ``per_doubling`` (a
    power of two), at least ``min_step``. ``per_doubling`` sizes per doubling, so at most
    ``1 + 1 / per_doubling`` times the count once ``step > min_step`` (never less than ``count``)."""
    step = max(min_step, 1 << max(0, (int(count) - 1).bit_length() - per_doubling.bit_length()))
    return -(-int(count) // step) * step
