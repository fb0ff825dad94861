"""Array sizes rounded up to a few per doubling, so that data of nearby sizes share one compile."""
from __future__ import annotations


def padded_size(count: int, minimum: int = 16) -> int:
    """``count`` rounded up to a multiple of a quarter of its octave (at least ``minimum``): four
    sizes per doubling, at most 1.25x the count (and never less than ``count``)."""
    quarter = max(minimum, 1 << max(0, (int(count) - 1).bit_length() - 3))
    return -(-int(count) // quarter) * quarter
