"""Hard-frame selection for active learning (off-road paper, Eq. 16) and its baselines.

Eq. 16: choose B frames u_1 < ... < u_B maximising ``sum FLR_u`` subject to ``|u_i - u_j| > Delta``
(no two chosen frames within Delta of each other, so near-duplicates are not annotated twice).
``select_hard_frames`` solves it exactly by dynamic programming over (frames seen, frames
chosen): ``best[t][b] = max(best[t-1][b], FLR_{t-1} + best[t-1-Delta][b-1])``, with
backtracking; O(T B) time. ``method="greedy"`` (highest FLR first, then its neighbours
excluded) is an option. Host-side (NumPy): T is a few thousand frames.
"""
from __future__ import annotations

import math

import jax
import numpy as np


def _check(flr, budget: int, gap: int) -> np.ndarray:
    values = np.asarray(flr, np.float64)
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"flr must be a non-empty 1-D array of frame-level risks, got shape {values.shape}")
    if not np.isfinite(values).all():
        raise ValueError(f"flr must be finite, got {int(values.size - np.isfinite(values).sum())} NaN/Inf value(s)")
    if int(budget) != budget or budget < 1:
        raise ValueError(f"budget must be an integer >= 1, got {budget}")
    if int(gap) != gap or gap < 0:
        raise ValueError(f"gap must be an integer >= 0, got {gap}")
    needed = (int(budget) - 1) * (int(gap) + 1) + 1
    if needed > values.size:
        raise ValueError(f"budget {budget} with gap {gap} needs at least {needed} frames, the sequence has {values.size}")
    return values


def _frames(num_frames) -> np.ndarray:
    """Zeros standing for ``num_frames`` frames; ValueError naming ``num_frames`` unless it is an integer >= 1."""
    if isinstance(num_frames, bool) or int(num_frames) != num_frames or num_frames < 1:
        raise ValueError(f"num_frames must be an integer >= 1, got {num_frames!r}")
    return np.zeros(int(num_frames))


def min_frames(budget: int, gap: int) -> int:
    """The shortest sequence that holds ``budget`` frames pairwise more than ``gap`` apart."""
    return (budget - 1) * (gap + 1) + 1


SELECTIONS = ("dp", "greedy")  # the methods of select_hard_frames


def select_hard_frames(flr, budget: int, gap: int, *, method: str = "dp") -> np.ndarray:
    """Eq. 16: indices ``(B,)`` (ascending) of B frames with maximal total FLR, pairwise > ``gap`` apart.

    ``method="dp"`` is exact (ties go to earlier frames); ``"greedy"`` takes the riskiest frame
    left (the earliest on ties) and drops its neighbours, and raises if that runs out of frames.
    """
    values = _check(flr, budget, gap)
    if method not in SELECTIONS:
        raise ValueError(f"method must be one of {SELECTIONS}, got {method!r}")
    if method == "greedy":
        return _greedy(values, int(budget), int(gap))
    t_total, b_total, step = values.size, int(budget), int(gap) + 1
    best = np.full((t_total + 1, b_total + 1), -np.inf)
    best[:, 0] = 0.0
    take = np.zeros((t_total + 1, b_total + 1), bool)
    for t in range(1, t_total + 1):
        with_t = values[t - 1] + best[max(t - step, 0), :-1]
        take[t, 1:] = with_t > best[t - 1, 1:]  # strict: on ties keep the earlier choice
        best[t] = best[t - 1]
        best[t, 1:] = np.where(take[t, 1:], with_t, best[t - 1, 1:])
    chosen, t, b = [], t_total, b_total
    while b > 0:
        if take[t, b]:
            chosen.append(t - 1)
            t, b = max(t - step, 0), b - 1
        else:
            t -= 1
    return np.asarray(chosen[::-1], np.int64)


def _greedy(values: np.ndarray, budget: int, gap: int) -> np.ndarray:
    free = np.ones(values.size, bool)
    chosen = []
    for t in np.argsort(-values, kind="stable"):
        if free[t]:
            chosen.append(t)
            free[max(t - gap, 0) : t + gap + 1] = False
            if len(chosen) == budget:
                return np.sort(np.asarray(chosen, np.int64))
    raise ValueError(f"greedy selection found only {len(chosen)} of budget {budget} frames with gap {gap}; use method='dp'")


def random_frames(key, num_frames: int, budget: int, gap: int = 0) -> np.ndarray:
    """The "Rand" baseline: B frames drawn uniformly among all sets pairwise > ``gap`` apart.

    A uniform B-subset s_1 < ... < s_B of ``range(T - (B-1) gap)`` maps one-to-one onto the valid
    sets by ``u_i = s_i + (i-1) gap``.
    """
    _check(_frames(num_frames), budget, gap)
    slots = int(num_frames) - (int(budget) - 1) * int(gap)
    picks = np.sort(np.asarray(jax.random.choice(key, slots, (int(budget),), replace=False)))
    return picks + np.arange(int(budget)) * int(gap)


def uniform_frames(num_frames: int, budget: int) -> np.ndarray:
    """The "Unif" baseline: ``floor((i + 1/2) T / B)`` for i = 0..B-1 (evenly spread, centred)."""
    _check(_frames(num_frames), budget, 0)
    return np.asarray([math.floor((i + 0.5) * num_frames / budget) for i in range(int(budget))], np.int64)
