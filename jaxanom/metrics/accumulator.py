"""Pooled anomaly metrics over a dataset fed one image at a time.

``exact`` mode keeps, per image, its distinct non-void scores (as sort keys) with the number of
positive and negative pixels at each, counts in the smallest unsigned dtype that holds them:
a 4-byte key (8 for float64) and two 1-4 byte counts per distinct score, so about 6 bytes per
pixel for float32 maps whose scores are mostly distinct (raw scores + labels: 5), and far less
for float16 or saturated scores, whose values repeat.
``compute`` merges the images and gives exactly ``anomaly_metrics`` of their concatenation.

``binned`` mode keeps two histograms (positive / negative pixels) of ``num_bins`` uniform bins
over a fixed ``score_range``: 16 bytes per bin whatever the dataset size. Its numbers are the
exact metrics of the binned scores (pixels of a bin tie), and ``compute`` states how far they
can be from the exact ones, from the histograms alone (see ``binned_error_bounds``).
"""
from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.metrics.anomaly import (check_conventions, check_scores_labels, require_both_classes,
                                     summary_to_metrics)
from jaxanom.metrics.binned import binned_error_bounds, score_histogram
from jaxanom.metrics.curve import curve_summary
from jaxanom.metrics.ranking import POSITIVE, VOID, sort_pixels
from jaxanom.shapes import padded_size

MODES = ("exact", "binned")


class AnomalyMetricAccumulator:
    """Collects images with ``update(scores, labels)``; ``compute()`` pools all of them.

    mode "exact" (default) or "binned"; binned needs ``score_range=(low, high)`` covering
    every non-void score (else ``update`` raises) and takes ``num_bins`` (default 65536).
    """

    def __init__(self, mode: str = "exact", *, score_range: tuple[float, float] | None = None,
                 num_bins: int = 65536):
        if mode not in MODES:
            raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
        if mode == "binned":
            if score_range is None or not float(score_range[0]) < float(score_range[1]):
                raise ValueError(f"score_range: expected (low, high) with low < high, got {score_range}")
            if int(num_bins) < 1:
                raise ValueError(f"num_bins: expected a positive integer, got {num_bins}")
            self.histogram = np.zeros((int(num_bins), 2), np.int64)  # [bin, (negative, positive)]
        self.mode, self.score_range, self.num_bins = mode, score_range, int(num_bins)
        self.images: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.counts = {"num_positives": 0, "num_negatives": 0, "num_void": 0}
        self.float64_keys: bool | None = None

    def update(self, scores, labels) -> None:
        """Add one image (or any batch): scores float (...), labels (...) in {0, 1, 255}."""
        with jax.enable_x64(True):
            scores, labels, counts = check_scores_labels(scores, labels)
            if self.mode == "exact":
                self._add_exact(scores, labels)
            else:
                self._add_binned(scores, labels)
        for name, value in counts.items():
            self.counts[name] += value

    def merge(self, other: "AnomalyMetricAccumulator") -> "AnomalyMetricAccumulator":
        """A new accumulator of the images of both (``self``'s first); neither is changed. Its
        ``compute`` equals that of one accumulator fed all the images."""
        if (other.mode, other.score_range, other.num_bins) != (self.mode, self.score_range, self.num_bins):
            raise ValueError(f"other: expected an accumulator of mode {self.mode!r}, score_range {self.score_range}, "
                             f"num_bins {self.num_bins}; got {other.mode!r}, {other.score_range}, {other.num_bins}")
        if None not in (self.float64_keys, other.float64_keys) and self.float64_keys != other.float64_keys:
            raise ValueError("other: expected scores of the same precision (float64 or not) as this accumulator's")
        merged = copy.copy(self)
        merged.images = self.images + other.images
        merged.counts = {name: value + other.counts[name] for name, value in self.counts.items()}
        merged.float64_keys = self.float64_keys if self.float64_keys is not None else other.float64_keys
        if self.mode == "binned":
            merged.histogram = self.histogram + other.histogram
        return merged

    def _add_exact(self, scores, labels) -> None:
        float64 = scores.dtype == jnp.float64
        if self.float64_keys is not None and float64 != self.float64_keys:
            raise ValueError(f"scores: expected {'float64' if self.float64_keys else 'float32 or narrower'} "
                             f"like the earlier images, got {scores.dtype}")
        self.float64_keys = float64
        keys, codes = (np.asarray(x) for x in _sort_pixels(scores, labels))
        real = codes != VOID
        keys, positive = keys[real], codes[real] == POSITIVE
        if keys.size == 0:
            return
        starts = np.flatnonzero(np.concatenate([[True], keys[1:] != keys[:-1]]))
        pixels = np.diff(np.append(starts, keys.size))
        positives = np.add.reduceat(positive.astype(np.int64), starts)
        count_dtype = np.min_scalar_type(int(pixels.max()))
        self.images.append((keys[starts].astype(np.uint64 if float64 else np.uint32),
                            positives.astype(count_dtype), (pixels - positives).astype(count_dtype)))

    def _add_binned(self, scores, labels) -> None:
        low, high = (float(x) for x in self.score_range)
        smallest, largest = (float(x) for x in _non_void_range(scores, labels))
        if smallest < low or largest > high:
            raise ValueError(f"scores: expected non-void scores within score_range {self.score_range}, "
                             f"got values in [{smallest}, {largest}]")
        self.histogram += np.asarray(_histogram(scores, labels, low, high, self.num_bins))

    def compute(self, *, fpr_convention: str = "first", ap_convention: str = "step",
                tpr: float = 0.95, conventions: bool = False) -> dict:
        """Metrics of all images so far, as ``anomaly_metrics`` returns them (``conventions``:
        with every AP / FPR convention's value too). Binned mode adds
        ``ap_error_bound``, ``auroc_error_bound``, ``fpr_error_bound`` (``|binned - exact| <= bound``)
        and has no "nearest" FPR; its thresholds are lower bin edges."""
        check_conventions(fpr_convention, ap_convention, tpr)
        require_both_classes(self.counts)
        if self.mode == "exact":
            keys, positives, negatives = _merge(self.images)
        else:
            if fpr_convention == "nearest":
                raise ValueError('fpr_convention: "nearest" has no error bound in binned mode; use mode="exact"')
            bins = np.arange(self.num_bins)[::-1]
            keys = (self.num_bins - 1 - bins).astype(np.uint32)
            positives, negatives = self.histogram[bins, 1], self.histogram[bins, 0]
        with jax.enable_x64(True):
            padded = _pad_to_few_sizes(keys, positives, negatives, self._count_dtype())
            summary = curve_summary(*padded, jnp.float64(tpr))
            metrics = summary_to_metrics(summary, self.counts, fpr_convention, ap_convention, tpr,
                                         bool(self.float64_keys), conventions)
        if self.mode == "binned":
            low, high = (float(x) for x in self.score_range)
            edge = lambda key: low + (self.num_bins - 1 - int(key)) * (high - low) / self.num_bins  # noqa: E731
            metrics["threshold_at_tpr"] = edge(summary["first_key"])
            metrics["best_f1_threshold"] = edge(summary["best_f1_key"])
            with jax.enable_x64(True):
                bounds = binned_error_bounds(positives, negatives, tpr, fpr_convention, ap_convention)
            metrics.update({name: float(value) for name, value in bounds.items()})
        return metrics

    def _count_dtype(self):
        """int32 for the cumulative counts below 2**31 non-void pixels (as ``anomaly_metrics``), else int64."""
        return np.int32 if self.counts["num_positives"] + self.counts["num_negatives"] < 2**31 else np.int64


def _merge(images):
    """Per-image (keys, positives, negatives) -> the same over all images, keys unique, sorted."""
    keys = np.concatenate([k for k, _, _ in images])
    unique, inverse = np.unique(keys, return_inverse=True)
    # bincount sums in float64, exact for counts below 2**53.
    total = lambda i: np.bincount(inverse, np.concatenate([c[i] for c in images]).astype(np.float64),  # noqa: E731
                                  unique.size).astype(np.int64)
    return unique, total(1), total(2)


def _pad_to_few_sizes(keys, positives, negatives, count_dtype):
    """Pad with empty entries under the largest key (no score has it) so that few array sizes,
    hence few compilations, occur: 16 sizes per power of two, so at most 1/16 more entries
    (``curve_summary`` holds ~100 bytes per entry: a power of two would cost up to 2x memory)."""
    pad = padded_size(max(int(keys.size), 1024), per_doubling=16, min_step=1) - keys.size
    keys = np.concatenate([keys, np.full(pad, np.iinfo(keys.dtype).max, keys.dtype)])
    zeros = np.zeros(pad, count_dtype)
    return (jnp.asarray(keys), jnp.asarray(np.concatenate([positives.astype(count_dtype), zeros])),
            jnp.asarray(np.concatenate([negatives.astype(count_dtype), zeros])))


_sort_pixels = jax.jit(sort_pixels)


@jax.jit
def _non_void_range(scores, labels):
    void = labels == 255
    return (jnp.min(jnp.where(void, jnp.inf, scores)), jnp.max(jnp.where(void, -jnp.inf, scores)))


_histogram = jax.jit(score_histogram, static_argnames=("low", "high", "num_bins"))  # its scale in float64
