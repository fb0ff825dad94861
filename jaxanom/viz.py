"""Pictures: score heat maps, overlays, label colourings, titled panel figures, ROC / PR plots.

All functions take host arrays and return uint8 RGB images (H, W, 3), or write PNG files
atomically. matplotlib is imported here only, so the numeric modules stay light.
"""
from __future__ import annotations

import dataclasses
import io
import os
from typing import Mapping, Sequence

import numpy as np

from jaxanom.io import write_bytes_atomic, write_png_atomic


def heatmap(score, *, vmin: float | None = None, vmax: float | None = None,
            cmap: str = "inferno") -> np.ndarray:
    """Score map (H, W) -> RGB uint8 (H, W, 3); ``vmin``/``vmax`` default to the finite range."""
    import matplotlib

    score = np.asarray(score, dtype=np.float64)
    if score.ndim != 2:
        raise ValueError(f"score: expected a map (H, W), got shape {score.shape}")
    lo, hi = _range(score, vmin, vmax)
    scaled = np.clip((score - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.zeros_like(score)
    scaled = np.nan_to_num(scaled, nan=0.0)
    rgba = matplotlib.colormaps[cmap](scaled, bytes=True)
    return np.ascontiguousarray(rgba[..., :3])


def _range(score: np.ndarray, vmin, vmax) -> tuple[float, float]:
    """``(vmin, vmax)``, each defaulting to the end of the finite values of ``score`` (0, 1 without any)."""
    finite = score[np.isfinite(score)]
    lo = vmin if vmin is not None else (float(finite.min()) if finite.size else 0.0)
    hi = vmax if vmax is not None else (float(finite.max()) if finite.size else 1.0)
    return float(lo), float(hi)


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


@dataclasses.dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class Panel:
    """One titled picture of a figure.

    ``image``: RGB uint8 (H, W, 3), drawn as it is (with ``legend``: ``(name, (r, g, b))`` pairs
    shown under it), or a score map (H, W) drawn through ``cmap`` over [``vmin``, ``vmax``]
    (default: its finite range, as ``heatmap``) with a colour bar named ``label``, laid over
    ``base`` (RGB uint8 (H, W, 3)) with opacity ``alpha`` when one is given.
    """

    title: str
    image: np.ndarray
    legend: tuple = ()
    vmin: float | None = None
    vmax: float | None = None
    cmap: str = "inferno"
    label: str = ""
    base: np.ndarray | None = None
    alpha: float = 0.6


def label_panel(title: str, labels, names: Sequence[str], palette: Sequence[Sequence[int]], *,
                void: tuple = ("void", (0, 0, 0))) -> Panel:
    """A label map (H, W) coloured by ``palette[id]`` (other ids: ``void``'s colour), with a legend
    of the classes it shows (and ``void`` when present)."""
    labels = np.asarray(labels)
    if len(names) != len(palette):
        raise ValueError(f"names, palette: expected equal lengths, got {len(names)} and {len(palette)}")
    present = np.unique(labels)
    legend = [(names[i], tuple(int(v) for v in palette[i])) for i in present if 0 <= i < len(names)]
    if ((labels < 0) | (labels >= len(names))).any():
        legend.append((void[0], tuple(int(v) for v in void[1])))
    return Panel(title, colorize(labels, palette, void_colour=void[1]), legend=tuple(legend))


def anomaly_label_panel(labels, title: str = "anomaly label") -> Panel:
    """An anomaly label map (H, W) (0 in-distribution, 1 anomaly, other ids void) with its legend."""
    return label_panel(title, labels, ("in-distribution", "anomaly"), ((40, 40, 40), (255, 0, 0)),
                       void=("void", (0, 0, 128)))


_DPI = 100
_TITLE = 28     # px above each picture
_BAR = 78       # px right of a score map: colour bar and its ticks
_GAP = 14       # px between cells and around the figure
_ENTRY = 19     # px per legend row


def _scale(width: int, min_width: int, max_width: int) -> float:
    """Display width / frame width: an integer factor up to ``min_width``, or down to ``max_width``."""
    if width < min_width:
        return float(-(-min_width // width))
    return min(1.0, max_width / width)


def _shown(panel: Panel, min_width: int, max_width: int) -> np.ndarray:
    """The RGB array drawn 1:1 for ``panel``: small frames repeated (nearest neighbour), large ones
    area-averaged down."""
    import cv2

    rgb = np.asarray(panel.image)
    if rgb.ndim == 2:
        rgb = heatmap(rgb, vmin=panel.vmin, vmax=panel.vmax, cmap=panel.cmap)
        if panel.base is not None:
            if np.shape(panel.base) != rgb.shape:
                raise ValueError(f"panel {panel.title!r}: base: expected RGB (H, W, 3) of the score's size "
                                 f"{rgb.shape}, got {np.shape(panel.base)}")
            rgb = overlay(panel.base, rgb, alpha=panel.alpha)
    if rgb.ndim != 3 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8 or 0 in rgb.shape:
        raise ValueError(f"panel {panel.title!r}: expected RGB uint8 (H, W, 3) or scores (H, W), "
                         f"got {np.asarray(panel.image).dtype} {np.asarray(panel.image).shape}")
    scale = _scale(rgb.shape[1], min_width, max_width)
    if scale >= 1:
        return np.repeat(np.repeat(rgb, int(scale), axis=0), int(scale), axis=1)
    size = (max(1, round(rgb.shape[1] * scale)), max(1, round(rgb.shape[0] * scale)))
    return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)


def _legend_columns(panel: Panel, width: int) -> int:
    longest = max(len(name) for name, _ in panel.legend)
    return max(1, min(len(panel.legend), width // (30 + 7 * longest)))


def panel_figure(panels: Sequence[Panel], *, columns: int = 3, min_width: int = 256, max_width: int = 1024):
    """A matplotlib ``Figure`` of ``panels`` in rows of ``columns``: each picture under its title,
    shown pixel for pixel at a readable width (frames narrower than ``min_width`` px repeated by an
    integer factor, i.e. nearest neighbour; wider than ``max_width`` averaged down), score maps
    with a colour bar, coloured labels with their legend."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    if not panels:
        raise ValueError("panels: expected at least one panel, got none")
    if columns < 1 or min_width < 1 or max_width < min_width:
        raise ValueError(f"columns, min_width, max_width: expected >= 1, >= 1, >= min_width, "
                         f"got {columns}, {min_width}, {max_width}")
    shown = [_shown(p, min_width, max_width) for p in panels]
    cells = []  # (width, height, picture height, legend rows) in px
    for panel, rgb in zip(panels, shown):
        h, w = rgb.shape[:2]
        rows = -(-len(panel.legend) // _legend_columns(panel, w)) if panel.legend else 0
        bar = _BAR if np.ndim(panel.image) == 2 else 0
        cells.append((w + bar, _TITLE + h + (rows * _ENTRY + 6 if rows else 0), h, rows))
    grid = [list(range(i, min(i + columns, len(panels)))) for i in range(0, len(panels), columns)]
    row_heights = [max(cells[i][1] for i in row) for row in grid]
    column_widths = [max(cells[i][0] for i in range(c, len(panels), columns)) for c in range(len(grid[0]))]
    width = _GAP + sum(w + _GAP for w in column_widths)
    height = _GAP + sum(h + _GAP for h in row_heights)
    figure = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")

    def box(x, y, w, h):  # px from the top-left -> figure fractions (left, bottom, width, height)
        return [x / width, 1 - (y + h) / height, w / width, h / height]

    top = _GAP
    for row, row_height in zip(grid, row_heights):
        left = _GAP
        for i, cell_width in zip(row, column_widths):
            panel, rgb, (_, _, h, rows) = panels[i], shown[i], cells[i]
            w = rgb.shape[1]
            axes = figure.add_axes(box(left, top + _TITLE, w, h))
            axes.imshow(rgb, interpolation="nearest", aspect="auto")
            axes.set(xticks=[], yticks=[])
            for spine in axes.spines.values():  # a thin frame: white regions stay visible
                spine.set(linewidth=0.6, edgecolor="0.6")
            axes.set_title(panel.title, fontsize=min(11.0, 1.6 * w / max(1, len(panel.title))), pad=6)
            if np.ndim(panel.image) == 2:
                lo, hi = _range(np.asarray(panel.image, np.float64), panel.vmin, panel.vmax)
                bar = figure.add_axes(box(left + w + 8, top + _TITLE, 14, h))
                figure.colorbar(ScalarMappable(Normalize(lo, hi if hi > lo else lo + 1), panel.cmap), cax=bar)
                bar.tick_params(labelsize=8)
                if panel.label:
                    bar.set_ylabel(panel.label, fontsize=8)
            if rows:
                handles = [Patch(facecolor=np.array(c) / 255, edgecolor="black", linewidth=0.5, label=name)
                           for name, c in panel.legend]
                figure.legend(handles=handles, loc="upper left", ncols=_legend_columns(panel, w), fontsize=8,
                              frameon=False, bbox_to_anchor=box(left, top + _TITLE + h + 2, 1, 1)[:2],
                              handlelength=1.2, handletextpad=0.4, columnspacing=0.8, borderpad=0.1,
                              borderaxespad=0)
            left += cell_width + _GAP
        top += row_height + _GAP
    return figure


def render_panels(panels: Sequence[Panel], **layout) -> np.ndarray:
    """``panel_figure(panels, **layout)`` drawn -> RGB uint8 (H, W, 3)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(panel_figure(panels, **layout))
    canvas.draw()
    return np.ascontiguousarray(np.asarray(canvas.buffer_rgba())[..., :3])


def write_panels(path: str | os.PathLike, panels: Sequence[Panel], **layout) -> None:
    """Write ``render_panels(panels, **layout)`` as a PNG, atomically."""
    write_png_atomic(path, render_panels(panels, **layout))


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
