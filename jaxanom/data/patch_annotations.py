"""A simulated annotator: a few labelled patches per frame, as a person marks them.

``annotate`` picks up to ``k`` square windows of side ``size`` that are at least ``purity``
pure in the reference labels, round-robin over the classes present (rarer classes are not
crowded out), and gives each picked class a label id that is meaningful only within the
frame: the ids are a random renumbering 0..n-1 per image, as two annotators (or one on two
days) would name the same terrain differently. The reference class of each patch is kept for
evaluation (docs/papers/offroad.md#evaluation) and never used in training. NumPy only (host side).
"""
from __future__ import annotations

import numpy as np


def window_counts(label: np.ndarray, num_classes: int, size: int) -> np.ndarray:
    """(H - size + 1, W - size + 1, num_classes) pixel counts of each class in every size x size window.

    Entry [r, c] counts the window with top-left corner (r, c); labels outside [0, num_classes)
    (void) count for no class.
    """
    onehot = (label[..., None] == np.arange(num_classes)).astype(np.int32)
    integral = np.pad(onehot.cumsum(0).cumsum(1), ((1, 0), (1, 0), (0, 0)))
    return (integral[size:, size:] - integral[:-size, size:] - integral[size:, :-size]
            + integral[:-size, :-size])


def annotate(label: np.ndarray, rng: np.random.Generator, *, k: int = 12, size: int = 32,
             purity: float = 0.9, num_classes: int = 10, stride: int = 4) -> dict[str, np.ndarray]:
    """Patch annotations of one frame.

    label: (H, W) reference class ids (255 = void). Returns ``"centers"`` (n, 2) int32 (row, col)
    with the window spanning rows ``r - size // 2 .. r - size // 2 + size - 1`` (likewise columns),
    ``"ids"`` (n,) int32 per-image label ids, ``"reference"`` (n,) int32 reference classes; n <= k
    (fewer where too few pure windows exist, 0 for a frame without any).
    """
    label = np.asarray(label)
    if label.ndim != 2 or min(label.shape) < size:
        raise ValueError(f"label: expected (H, W) with H, W >= size={size}, got shape {label.shape}")
    if not 0.5 < purity <= 1.0 or k < 1 or stride < 1:
        raise ValueError(f"purity, k, stride: expected 0.5 < purity <= 1, k >= 1, stride >= 1, got {purity}, {k}, {stride}")
    counts = window_counts(label, num_classes, size)[::stride, ::stride]
    pure = counts >= purity * size * size  # at most one class per window since purity > 0.5
    candidates = {c: list(rng.permutation(np.argwhere(pure[..., c]))) for c in range(num_classes) if pure[..., c].any()}
    order = list(rng.permutation(sorted(candidates)))
    picked: list[tuple[int, int, int]] = []
    while len(picked) < k and any(candidates[c] for c in order):
        for cls in order:
            if candidates[cls] and len(picked) < k:
                r, c = candidates[cls].pop()
                picked.append((r * stride + size // 2, c * stride + size // 2, int(cls)))
    reference = np.array([p[2] for p in picked], np.int32)
    present = np.unique(reference)
    ids = rng.permutation(len(present)).astype(np.int32)[np.searchsorted(present, reference)]
    centers = np.array([p[:2] for p in picked], np.int32).reshape(-1, 2)
    return {"centers": centers, "ids": ids, "reference": reference}
