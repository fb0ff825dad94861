"""Hard-frame selection (Eq. 16) against brute force, and the baselines."""
import itertools

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxanom.offroad import active


def brute_force(flr, budget, gap):
    best = -np.inf
    for subset in itertools.combinations(range(len(flr)), budget):
        if all(b - a > gap for a, b in zip(subset, subset[1:])):
            best = max(best, sum(flr[i] for i in subset))
    return best


def respects_gap(frames, gap):
    return all(abs(a - b) > gap for a, b in itertools.combinations(frames, 2))


@settings(max_examples=80, deadline=None)
@given(st.lists(st.integers(0, 10), min_size=1, max_size=14), st.integers(1, 4), st.integers(0, 3))
def test_dp_is_optimal_against_brute_force(values, budget, gap):
    flr = np.asarray(values, np.float64) / 10  # small integers: many ties
    if active.min_frames(budget, gap) > len(flr):
        with pytest.raises(ValueError, match="budget"):
            active.select_hard_frames(flr, budget, gap)
        return
    frames = active.select_hard_frames(flr, budget, gap)
    assert len(frames) == budget and len(set(frames.tolist())) == budget
    assert respects_gap(frames, gap)
    assert (np.diff(frames) > 0).all()
    np.testing.assert_allclose(flr[frames].sum(), brute_force(flr, budget, gap), atol=1e-12)


def test_dp_beats_greedy_where_greedy_is_suboptimal():
    flr = np.array([0.6, 1.0, 0.6])  # greedy takes the middle (1.0); the DP takes both ends (1.2)
    np.testing.assert_array_equal(active.select_hard_frames(flr, 2, 0), [0, 1])
    np.testing.assert_array_equal(active.select_hard_frames(flr, 2, 1), [0, 2])
    with pytest.raises(ValueError, match="greedy selection found only 1"):
        active.select_hard_frames(flr, 2, 1, method="greedy")
    np.testing.assert_array_equal(active.select_hard_frames([0.1, 0.9, 0.2, 0.8, 0.3], 2, 1, method="greedy"), [1, 3])


def test_gap_always_holds_on_long_random_sequences():
    rng = np.random.default_rng(0)
    for _ in range(5):
        flr = rng.random(400)
        frames = active.select_hard_frames(flr, 20, 10)
        assert respects_gap(frames, 10)
        assert flr[frames].sum() >= flr[active.uniform_frames(400, 20)].sum()


def test_random_frames_respect_the_gap_and_are_uniform_over_valid_sets():
    counts = {}
    for seed in range(3000):
        frames = active.random_frames(jax.random.key(seed), 7, 2, 2)
        assert respects_gap(frames, 2)
        counts[tuple(frames.tolist())] = counts.get(tuple(frames.tolist()), 0) + 1
    valid = [s for s in itertools.combinations(range(7), 2) if s[1] - s[0] > 2]
    assert set(counts) == set(valid)  # 10 valid sets, each ~300 times
    assert max(counts.values()) < 1.35 * min(counts.values())
    np.testing.assert_array_equal(active.random_frames(jax.random.key(1), 9, 3, 3), [0, 4, 8])  # the only valid set


def test_uniform_frames():
    np.testing.assert_array_equal(active.uniform_frames(10, 2), [2, 7])
    np.testing.assert_array_equal(active.uniform_frames(100, 4), [12, 37, 62, 87])
    np.testing.assert_array_equal(active.uniform_frames(3, 3), [0, 1, 2])
    np.testing.assert_array_equal(active.uniform_frames(1, 1), [0])  # a one-frame sequence: floor(1/2)


def test_a_one_frame_sequence_gives_that_frame():
    np.testing.assert_array_equal(active.random_frames(jax.random.key(0), 1, 1), [0])
    np.testing.assert_array_equal(active.select_hard_frames(np.array([0.3]), 1, 0), [0])


def test_bad_input_raises_naming_the_argument():
    with pytest.raises(ValueError, match="budget 3 with gap 4 needs at least 11 frames, the sequence has 10"):
        active.select_hard_frames(np.zeros(10), 3, 4)
    with pytest.raises(ValueError, match="budget 5 .* the sequence has 4"):
        active.uniform_frames(4, 5)
    with pytest.raises(ValueError, match="budget"):
        active.random_frames(jax.random.key(0), 5, 3, 2)
    with pytest.raises(ValueError, match="budget must be an integer >= 1"):
        active.select_hard_frames(np.zeros(10), 0, 1)
    with pytest.raises(ValueError, match="gap must be an integer >= 0"):
        active.select_hard_frames(np.zeros(10), 2, -1)
    with pytest.raises(ValueError, match="flr must be finite"):
        active.select_hard_frames(np.array([0.1, np.nan, 0.3]), 1, 0)
    with pytest.raises(ValueError, match="flr must be a non-empty"):
        active.select_hard_frames([], 1, 0)
    with pytest.raises(ValueError, match="method must be"):
        active.select_hard_frames(np.zeros(3), 1, 0, method="beam")


@pytest.mark.parametrize("num_frames", [0, -2, 2.5, True])
def test_frame_counts_are_checked_under_their_own_name(num_frames):
    with pytest.raises(ValueError, match=f"num_frames must be an integer >= 1, got {num_frames!r}"):
        active.uniform_frames(num_frames, 1)
    with pytest.raises(ValueError, match=f"num_frames must be an integer >= 1, got {num_frames!r}"):
        active.random_frames(jax.random.key(0), num_frames, 1)
