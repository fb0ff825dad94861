"""Bootstrap intervals over frames (and seeds) from per-frame histograms, shared by every experiment.

A pooled pixel metric (AP, FPR at 95% TPR, AUROC) is a function of the (negative, positive) pixel
counts per score bin, so a bootstrap replicate that resamples frames is a weighted sum of per-frame
histograms (``frame_histograms``) over ``NUM_BINS`` bins at the quantiles of the pooled scores: a
matrix product instead of a sort. Every row compared is resampled with the same draws (paired), so
the interval of a difference comes from the differences of the replicates (``difference``); two
networks scored on the same frames and resampled with the same draws are paired the same way
(``network_difference``, ``difference_change``).

``hierarchical_draws`` adds a level for several seeds: a replicate draws seeds with replacement and,
inside each drawn seed, its frames with replacement; a row's replicate value is the mean over the
drawn seeds of the metric on the drawn frames (``hierarchical``). With one seed it is the frame
bootstrap.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, Mapping, Sequence

import numpy as np

NUM_BINS = 20_000
REPLICATES = 1000

def bin_edges(scores: list[np.ndarray], labels: list[np.ndarray], num_bins: int = NUM_BINS) -> np.ndarray:
    """Increasing inner bin edges at the quantiles of the pooled non-void scores (ties merge bins)."""
    pooled = np.concatenate([s[l != 255].ravel() for s, l in zip(scores, labels)]).astype(np.float64)
    return np.unique(np.quantile(pooled, np.linspace(0, 1, num_bins + 1)[1:-1]))


def frame_histograms(scores: list[np.ndarray], labels: list[np.ndarray], edges: np.ndarray) -> np.ndarray:
    """(F, len(edges) + 1, 2) int64: per frame, per bin, (negative, positive) non-void pixels;
    bin b holds scores in [edges[b-1], edges[b])."""
    out = np.zeros((len(scores), edges.size + 1, 2), np.int64)
    for f, (score, label) in enumerate(zip(scores, labels)):
        keep = label != 255
        bins = np.searchsorted(edges, score[keep].astype(np.float64), side="right")
        out[f, :, 0] = np.bincount(bins[label[keep] == 0], minlength=edges.size + 1)
        out[f, :, 1] = np.bincount(bins[label[keep] == 1], minlength=edges.size + 1)
    return out


def binned_metrics(histograms: np.ndarray, tpr: float = 0.95) -> dict[str, np.ndarray]:
    """AP (step: sum_k dR_k Prec_k), envelope AP (MMF Eq. 7: sum_k dR_k max_{j >= k} Prec_j) and
    FPR at the first threshold with TPR >= ``tpr`` of pooled histograms (..., bins, 2), thresholds
    from the highest bin down; pixels of a bin tie."""
    neg, pos = histograms[..., ::-1, 0].astype(np.float64), histograms[..., ::-1, 1].astype(np.float64)
    tp, fp = np.cumsum(pos, -1), np.cumsum(neg, -1)
    p, n = tp[..., -1:], fp[..., -1:]
    precision = tp / np.maximum(tp + fp, 1.0)
    envelope = np.maximum.accumulate(precision[..., ::-1], -1)[..., ::-1]  # an empty bin repeats an earlier point
    ap, ap_envelope = (pos / p * precision).sum(-1), (pos / p * envelope).sum(-1)
    first = np.argmax(tp / p >= tpr, axis=-1)
    fpr = np.take_along_axis(fp, first[..., None], -1)[..., 0] / n[..., 0]
    return {"ap": ap, "ap_envelope": ap_envelope, "fpr_at_tpr": fpr}


def draws(num_frames: int, replicates: int = REPLICATES, seed: int = 0) -> np.ndarray:
    """(replicates, num_frames) multiplicities of each frame in each bootstrap replicate."""
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, num_frames, size=(replicates, num_frames))
    return np.stack([np.bincount(row, minlength=num_frames) for row in picks])


def bootstrap(histograms: np.ndarray, multiplicities: np.ndarray) -> dict[str, np.ndarray]:
    """Metrics of every replicate, (replicates,) per metric: frames pooled with their multiplicities."""
    parts = []
    for start in range(0, len(multiplicities), 50):  # 50 replicates at a time bound the memory
        pooled = np.einsum("rf,fbc->rbc", multiplicities[start:start + 50].astype(np.float64), histograms)
        with np.errstate(invalid="ignore", divide="ignore"):
            parts.append(binned_metrics(pooled))
    return {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}


def interval(values: np.ndarray) -> tuple[float, float]:
    """The 95% percentile interval of bootstrap values (NaN replicates, e.g. without an anomaly, left out)."""
    low, high = np.nanpercentile(values, [2.5, 97.5])
    return float(low), float(high)


def binned_auroc(histograms: np.ndarray) -> np.ndarray:
    """Area under the ROC curve (trapezoid) of pooled histograms (..., bins, 2), one ROC point per bin
    from the highest bin down (pixels of a bin tie)."""
    neg, pos = histograms[..., ::-1, 0].astype(np.float64), histograms[..., ::-1, 1].astype(np.float64)
    tpr = np.cumsum(pos, -1) / pos.sum(-1, keepdims=True)
    fpr = np.cumsum(neg, -1) / neg.sum(-1, keepdims=True)
    tpr_before = np.concatenate([np.zeros_like(tpr[..., :1]), tpr[..., :-1]], -1)
    return (np.diff(fpr, prepend=0.0, axis=-1) * (tpr + tpr_before) / 2).sum(-1)


def difference(replicates: dict, a: str, b: str, metric: str) -> tuple[float, float]:
    """95% interval of ``metric(a) - metric(b)`` over paired replicates."""
    return interval(replicates[a][metric] - replicates[b][metric])


def network_difference(first: dict, second: dict, name: str, metric: str) -> tuple[float, float]:
    """95% interval of ``metric(name)`` under ``first`` minus under ``second``: replicates of two networks
    on the same frames, drawn with the same multiplicities (paired)."""
    return interval(first[name][metric] - second[name][metric])


def difference_change(first: dict, second: dict, a: str, b: str, metric: str) -> tuple[float, float]:
    """95% interval of how ``metric(a) - metric(b)`` changes from ``second`` to ``first`` (two networks'
    paired replicates, as ``network_difference``): whether a finding's gap grows or shrinks."""
    return interval((first[a][metric] - first[b][metric]) - (second[a][metric] - second[b][metric]))


# ----------------------------------------------------------------------------- seeds and frames
@dataclasses.dataclass(frozen=True)
class Draws:
    """Hierarchical bootstrap draws of ``replicates`` replicates over S seeds.

    ``seeds`` (R, S) int: the seed drawn into each of a replicate's S slots. ``frames[kind]`` (R, S,
    max count) int: how often each frame of that slot's seed is drawn (zero past the seed's count);
    ``counts[kind]``: the frames of each seed. Kinds are frame sets drawn independently (e.g. anomaly
    frames and validation frames) under the same seed draws.
    """

    seeds: np.ndarray
    frames: Mapping[str, np.ndarray]
    counts: Mapping[str, tuple[int, ...]]


def hierarchical_draws(counts: Mapping[str, Sequence[int]], replicates: int = REPLICATES, seed: int = 0) -> Draws:
    """Seeds with replacement, then each drawn seed's frames of every kind with replacement.

    ``counts[kind]``: frames of each seed (one entry per seed, every kind the same seeds).
    Deterministic in ``seed``.
    """
    sizes = {kind: tuple(int(c) for c in v) for kind, v in counts.items()}
    num_seeds = {len(v) for v in sizes.values()}
    if len(num_seeds) != 1 or 0 in num_seeds:
        raise ValueError(f"counts: expected the same positive number of seeds for every kind, got {sizes}")
    if min(min(v) for v in sizes.values()) < 1:
        raise ValueError(f"counts: expected at least one frame per seed, got {sizes}")
    if replicates < 1:
        raise ValueError(f"replicates: expected >= 1, got {replicates}")
    (s,) = num_seeds
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, s, size=(replicates, s))
    frames = {}
    for kind in sorted(sizes):
        n = np.asarray(sizes[kind])[picks][..., None]  # (R, S, 1) frames of each drawn seed
        width = max(sizes[kind])
        index = rng.integers(0, n, size=(replicates, s, width))
        slot = np.arange(replicates * s).reshape(replicates, s, 1) * width
        flat = (slot + index)[np.arange(width) < n]
        frames[kind] = np.bincount(flat, minlength=replicates * s * width).reshape(replicates, s, width)
    return Draws(picks, frames, sizes)


def hierarchical(items: Sequence[np.ndarray], draws: Draws, kind: str,
                 metric: Callable[[np.ndarray], dict[str, np.ndarray]], chunk: int = 50) -> dict[str, np.ndarray]:
    """(R,) replicates per metric name: the mean over a replicate's slots of ``metric`` of the drawn
    seed's frames pooled with their multiplicities.

    ``items[s]``: (F_s, ...) per-frame counts of seed s (histograms, confusion matrices), F_s =
    ``draws.counts[kind][s]``; ``metric(pooled (n, ...)) -> {name: (n,)}``.
    """
    counts = draws.counts[kind]
    if [len(x) for x in items] != list(counts):
        raise ValueError(f"items: expected frames per seed {list(counts)}, got {[len(x) for x in items]}")
    values: dict[str, np.ndarray] = {}
    for s, per_frame in enumerate(items):
        r, k = np.nonzero(draws.seeds == s)
        weights = draws.frames[kind][r, k, :len(per_frame)].astype(np.float64)
        for start in range(0, len(r), chunk):  # ``chunk`` pooled replicates at a time bound the memory
            pooled = np.tensordot(weights[start:start + chunk], per_frame.astype(np.float64), axes=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                for name, value in metric(pooled).items():
                    values.setdefault(name, np.full(draws.seeds.shape, np.nan))[r[start:start + chunk],
                                                                                  k[start:start + chunk]] = value
    with np.errstate(invalid="ignore"):
        return {name: v.mean(1) for name, v in values.items()}
