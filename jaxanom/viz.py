"""Pictures: score heat maps, overlays, label colourings, ROC / PR plots (NumPy + matplotlib).

All functions take host arrays and return uint8 RGB images (H, W, 3), or write PNG files
atomically. matplotlib is imported here only, so the numeric modules stay light.
"""
from __future__ import annotations

import io
import os
from typing import Mapping, Sequence

import numpy as np

from jaxanom.io import write_bytes_atomic


def heatmap(score, *, vmin: float | None = None, vmax: float | None = None,
            cmap: str = "inferno") -> np.ndarray:
    """Score map (H, W) -> RGB uint8 (H, W, 3); ``vmin``/``vmax`` default to the finite range."""
    import matplotlib

    score = np.asarray(score, dtype=np.float64)
    if score.ndim != 2:
        raise ValueError(f"score: expected a map (H, W), got shape {score.shape}")
    finite = score[np.isfinite(score)]
    lo = vmin if vmin is not None else (float(finite.min()) if finite.size else 0.0)
    hi = vmax if vmax is not None else (float(finite.max()) if finite.size else 1.0)
    scaled = np.clip((score - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.zeros_like(score)
    scaled = np.nan_to_num(scaled, nan=0.0)
    rgba = matplotlib.colormaps[cmap](scaled, bytes=True)
    return np.ascontiguousarray(rgba[..., :3])


def overlay(image, colours, *, alpha: float = 0.5, mask=None) -> np.ndarray:
    """Blend ``colours`` over ``image`` (both RGB uint8 (H, W, 3)): ``(1-alpha)*image + alpha*colours``.

    With a bool ``mask`` (H, W), only masked pixels are blended; the rest keep the image.
    """
    image, colours = np.asarray(image), np.asarray(colours)
    if image.shape != colours.shape or image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"image/colours: expected equal (H, W, 3) shapes, got {image.shape} and {colours.shape}")
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha: expected a value in [0, 1], got {alpha}")
    blended = (1.0 - alpha) * image.astype(np.float64) + alpha * colours.astype(np.float64)
    blended = np.rint(blended).astype(np.uint8)
    if mask is not None:
        blended = np.where(np.asarray(mask, dtype=bool)[..., None], blended, image)
    return blended


def colorize(labels, palette: Sequence[Sequence[int]], *, void_colour=(0, 0, 0)) -> np.ndarray:
    """Label map (H, W) of class ids -> RGB uint8 (H, W, 3) via ``palette[id]``; other ids get ``void_colour``."""
    labels = np.asarray(labels)
    table = np.array(list(palette) + [void_colour], dtype=np.uint8)
    index = np.where((labels >= 0) & (labels < len(palette)), labels, len(palette))
    return table[index]


def panel_row(panels: Sequence[np.ndarray], titles: Sequence[str], *, strip: int = 18) -> np.ndarray:
    """RGB uint8 panels (H, W_i, 3) side by side, each under a white strip with its title in black."""
    import cv2

    if len(panels) != len(titles) or not panels:
        raise ValueError(f"panels, titles: expected equal non-zero counts, got {len(panels)} and {len(titles)}")
    titled = []
    for panel, title in zip(panels, titles):
        header = np.full((strip, panel.shape[1], 3), 255, np.uint8)
        scale = min(0.45, 0.9 * panel.shape[1] / max(1, 10 * len(title)))  # long titles on narrow panels shrink
        cv2.putText(header, title, (3, strip - 5), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
        titled.append(np.concatenate([header, np.asarray(panel, np.uint8)], axis=0))
    return np.concatenate(titled, axis=1)


def plot_curves(path: str | os.PathLike, curves: Mapping[str, tuple], *, kind: str = "roc") -> None:
    """Write a PNG with one line per method: ``curves[name] = (x, y)``.

    ``kind="roc"``: x = FPR, y = TPR, with the chance diagonal; ``kind="pr"``: x = recall,
    y = precision.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    if kind not in ("roc", "pr"):
        raise ValueError(f"kind: expected 'roc' or 'pr', got {kind!r}")
    figure = Figure(figsize=(5, 4.5), dpi=100)
    axes = figure.add_subplot()
    for name, (x, y) in curves.items():
        axes.plot(np.asarray(x), np.asarray(y), label=name, linewidth=1.4)
    if kind == "roc":
        axes.plot([0, 1], [0, 1], color="grey", linestyle=":", linewidth=1)
        axes.set(xlabel="false positive rate", ylabel="true positive rate", title="ROC")
    else:
        axes.set(xlabel="recall", ylabel="precision", title="precision-recall")
    axes.set(xlim=(0, 1), ylim=(0, 1.02))
    axes.grid(alpha=0.3)
    axes.legend(fontsize=7, loc="lower right" if kind == "roc" else "upper right")
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    write_bytes_atomic(path, buffer.getvalue())


def score_figure(image, score, *, title: str, label: str = "anomaly score", cmap: str = "inferno",
                 alpha: float = 0.6, width: int = 1600) -> np.ndarray:
    """A picture for people: ``image`` (H, W, 3) uint8 RGB and ``score`` (H, W) laid over it as a
    heat map, in two titled panels with a colour bar of the score's values; ``width`` pixels wide.

    Returns RGB uint8. The colour range is the score's finite range on this image.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    image, score = np.asarray(image), np.asarray(score, np.float64)
    if image.ndim != 3 or image.shape[-1] != 3 or image.shape[:2] != score.shape:
        raise ValueError(f"image, score: expected (H, W, 3) and (H, W) of one size, got {image.shape} and {score.shape}")
    finite = score[np.isfinite(score)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    high = high if high > low else low + 1.0
    dpi, bar = 100, 0.035
    panel = width / dpi / (2 + bar + 0.2)
    figure = Figure(figsize=(width / dpi, panel * image.shape[0] / image.shape[1] + 0.9), dpi=dpi)
    FigureCanvasAgg(figure)
    left, right, scale = figure.subplots(1, 3, gridspec_kw={"width_ratios": [1, 1, bar]})
    left.imshow(image)
    left.set_title("image", fontsize=12)
    right.imshow(overlay(image, heatmap(score, vmin=low, vmax=high, cmap=cmap), alpha=alpha))
    right.set_title(label, fontsize=12)
    for axes in (left, right):
        axes.set_axis_off()
    figure.suptitle(title, fontsize=13)
    figure.colorbar(ScalarMappable(Normalize(low, high), cmap), cax=scale).ax.tick_params(labelsize=10)
    figure.subplots_adjust(left=0.01, right=0.95, bottom=0.03, top=0.87, wspace=0.04)
    figure.canvas.draw()
    return np.ascontiguousarray(np.asarray(figure.canvas.buffer_rgba())[..., :3])
