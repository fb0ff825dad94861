"""Independent NumPy/SciPy references for SML, written from the equations and docs/papers/sml-cudam-msaam.md#standardized-max-logits.

Everything here is float64 and loops or calls scipy.ndimage; nothing imports jaxanom.
"""
import math

import numpy as np
from scipy import ndimage

CROSS = ndimage.generate_binary_structure(2, 1)


def boundaries(label: np.ndarray, border: str) -> np.ndarray:
    """Cross dilation != square erosion, with explicit padding per border mode."""
    if border == "geodesic":
        dil_pad = dict(mode="edge")
        ero_pad = dict(mode="edge")
    else:  # the original's kornia: dilation pads 0, erosion pads 1.0
        dil_pad = dict(mode="constant", constant_values=0)
        ero_pad = dict(mode="constant", constant_values=1)
    lab = label.astype(np.float64)
    dil = ndimage.grey_dilation(np.pad(lab, 1, **dil_pad), footprint=CROSS)[1:-1, 1:-1]
    ero = ndimage.grey_erosion(np.pad(lab, 1, **ero_pad), size=(3, 3))[1:-1, 1:-1]
    return dil != ero


def expand(boundary: np.ndarray, r: int) -> np.ndarray:
    """Binary dilation by the diamond of radius r (the original's d_ks[r]), zeros outside."""
    if r == 0:
        return boundary.copy()
    diamond = ndimage.iterate_structure(CROSS, r)
    return ndimage.binary_dilation(boundary, structure=diamond, border_value=0)


def suppress(score: np.ndarray, label: np.ndarray, width=4, iterations=4, border="geodesic") -> np.ndarray:
    """Eqs. 6-7 with an explicit Python loop over band pixels and their 3x3 windows."""
    out = score.astype(np.float64).copy()
    h, w = out.shape
    b = boundaries(label, border)
    step = width // iterations
    for it in range(iterations):
        r = 0 if (width == 0 or it == iterations - 1) else width - step * it - 1
        band = expand(b, r)
        prev = out.copy()
        for y in range(h):
            for x in range(w):
                if not band[y, x]:
                    continue
                total, count = 0.0, 0
                for dy in (-1, 0, 1):
                    for dx in (-1, 0, 1):
                        yy, xx = min(max(y + dy, 0), h - 1), min(max(x + dx, 0), w - 1)  # replication
                        if not band[yy, xx]:
                            total += prev[yy, xx]
                            count += 1
                if count:
                    out[y, x] = total / count
    return out


def gaussian_2d(size=7, sigma=1.0) -> np.ndarray:
    """The original's normalised 2-D Gaussian (np.fromfunction of the density)."""
    c = (size - 1) / 2
    k = np.fromfunction(lambda x, y: np.exp(-((x - c) ** 2 + (y - c) ** 2) / (2 * sigma**2)) / (2 * math.pi * sigma**2), (size, size))
    return k / k.sum()


def smooth(score: np.ndarray, size=7, sigma=1.0, dilation=6) -> np.ndarray:
    """Dilated 2-D correlation after replication padding of dilation * (size // 2)."""
    k = gaussian_2d(size, sigma)
    dilated = np.zeros(((size - 1) * dilation + 1,) * 2)
    dilated[::dilation, ::dilation] = k
    pad = dilation * (size // 2)
    full = ndimage.correlate(np.pad(score.astype(np.float64), pad, mode="edge"), dilated, mode="constant")
    return full[pad:-pad, pad:-pad] if pad else full


def standardize(logits: np.ndarray, mean: np.ndarray, std: np.ndarray):
    """Eq. 5 in float64: (max logit - mean[argmax]) / std[argmax], and the argmax."""
    pred = np.argmax(logits, axis=-1)
    return (logits.max(-1).astype(np.float64) - mean[pred]) / std[pred], pred


def class_stats(logits_list, valid_list=None):
    """Per-class count, mean, unbiased var of the max logit over predicted pixels (float64)."""
    c = logits_list[0].shape[-1]
    values = [[] for _ in range(c)]
    for i, lg in enumerate(logits_list):
        valid = np.ones(lg.shape[:-1], bool) if valid_list is None else valid_list[i]
        pred, mx = np.argmax(lg, -1), lg.max(-1).astype(np.float64)
        for k in range(c):
            values[k].extend(mx[(pred == k) & valid].tolist())
    count = np.array([len(v) for v in values], float)
    mean = np.array([np.mean(v) if v else 0.0 for v in values])
    var = np.array([np.var(v, ddof=1) if len(v) > 1 else np.nan for v in values])
    return count, mean, var
