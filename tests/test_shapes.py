"""``shapes.padded_size``: a few sizes per doubling, never below the count, at most 1.25x above it."""
import pytest

from jaxanom.shapes import padded_size


def test_padded_sizes_are_quarter_octave_multiples_at_or_above_the_count():
    for count in range(1, 5000):
        size = padded_size(count)
        octave = 1 << (count - 1).bit_length()  # the power of two at or above the count
        step = max(16, octave // 8)
        assert size >= count and size % step == 0 and size - count < step, (count, size)
        assert count < 64 or size <= 1.25 * count, (count, size)


@pytest.mark.parametrize("low", [64, 256, 4096, 2**20])
def test_four_sizes_per_doubling(low):
    assert sorted({padded_size(c) for c in range(low + 1, 2 * low + 1)}) == [low * k // 4 for k in (5, 6, 7, 8)]


@pytest.mark.parametrize("per_doubling", [8, 16])
@pytest.mark.parametrize("low", [1024, 2**20])
def test_per_doubling_sizes_per_doubling(per_doubling, low):
    sizes = sorted({padded_size(c, per_doubling=per_doubling, min_step=1) for c in range(low + 1, 2 * low + 1)})
    assert sizes == [low * k // per_doubling for k in range(per_doubling + 1, 2 * per_doubling + 1)]


def test_a_larger_minimum_step():
    assert [padded_size(c, min_step=64) for c in (1, 64, 65, 200)] == [64, 64, 128, 256]
    assert [padded_size(c, per_doubling=8, min_step=1) for c in (1, 2, 3, 17)] == [1, 2, 3, 18]
