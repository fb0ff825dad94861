"""DeepScene / Freiburg Forest reader (Valada et al., ISER 2016), in the dataset's own layout.

Layout (``freiburg_forest_annotated``): ``<root>/{train,test}/rgb/<stem>_Clipped.jpg`` and
``<root>/{train,test}/GT_color/<stem>_mask.png``: colour-coded labels; image and label are
paired by ``<stem>`` (the file name up to its first underscore). Colours (``COLOURS``): trail
(170,170,170), grass (0,255,0), vegetation (102,102,51), sky (0,120,255), obstacle (0,0,0),
void (255,255,255); some releases draw trees apart, (0,60,0), counted as vegetation. Labels
come back as ``DEEPSCENE_CLASSES`` ids 0..4 (the order of ``jaxanom.data.offroad``'s
``"deepscene"`` granularity) and 255 for void. Colours are matched to the nearest palette entry
within ``tolerance`` per channel (JPEG-compressed label files exist); a pixel farther from every
entry is an error naming the file.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from jaxanom.data.frames import FrameReader
from jaxanom.data.image_io import require_dir, require_file
from jaxanom.errors import InputError

DEEPSCENE_CLASSES = ("trail", "grass", "vegetation", "sky", "obstacle")
COLOURS = {(170, 170, 170): 0, (0, 255, 0): 1, (102, 102, 51): 2, (0, 60, 0): 2, (0, 120, 255): 3, (0, 0, 0): 4,
           (255, 255, 255): 255}


def decode_colours(rgb: np.ndarray, colours: dict, path: Path, tolerance: int) -> np.ndarray:
    """(H, W, 3) uint8 colour-coded labels -> (H, W) uint8 ids of the nearest colour in ``colours``."""
    palette = np.array(list(colours), np.int32)
    ids = np.array(list(colours.values()), np.uint8)
    distance = np.abs(rgb[:, :, None, :].astype(np.int32) - palette[None, None]).max(-1)
    nearest = distance.argmin(-1)
    far = np.take_along_axis(distance, nearest[..., None], -1)[..., 0] > tolerance
    if far.any():
        r, c = np.argwhere(far)[0]
        raise InputError("label", f": {int(far.sum())} pixel(s) of {path} match no class colour within {tolerance} "
                         f"(first at row {r}, column {c}: {rgb[r, c].tolist()})")
    return ids[nearest]


def read_colour_label(path: Path) -> np.ndarray:
    """A colour-coded label image -> (H, W, 3) uint8 RGB."""
    image = cv2.imread(str(require_file(path, "label")), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError("label", f": cannot decode {path} (corrupt or unsupported format)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


class ColourFrames(FrameReader):
    """FrameReader whose label files are colour images."""

    def __init__(self, frames, colours: dict, tolerance: int):
        super().__init__(frames, lambda raw, path: raw)
        self._colours, self._tolerance = colours, tolerance

    def __getitem__(self, index: int):
        if not 0 <= index < len(self.frames):
            raise IndexError(f"index {index} out of range for {len(self.frames)} frames")
        name, _, label_path = self.frames[index]
        image = self.read_image(index)
        label = decode_colours(read_colour_label(label_path), self._colours, label_path, self._tolerance)
        if label.shape != image.shape[:2]:
            raise InputError("label", f": size {label.shape} of {label_path} differs from its image's {image.shape[:2]}")
        return {"image": image, "label": label, "name": name}


class DeepScene(ColourFrames):
    """``DeepScene(root, "train" | "test")[i]`` -> image, label (0..4, 255 void), name (the stem)."""

    def __init__(self, root: str | Path, split: str = "train", *, tolerance: int = 40):
        if split not in ("train", "test"):
            raise ValueError(f"split: expected 'train' or 'test', got {split!r}")
        rgb_dir = require_dir(Path(root) / split / "rgb", "DeepScene images")
        gt_dir = require_dir(Path(root) / split / "GT_color", "DeepScene colour labels")
        labels = {p.name.split("_")[0]: p for p in sorted(gt_dir.iterdir()) if p.suffix.lower() in (".png", ".jpg")}
        frames = []
        for image in sorted(p for p in rgb_dir.iterdir() if p.suffix.lower() in (".jpg", ".png")):
            stem = image.name.split("_")[0]
            if stem not in labels:
                raise FileNotFoundError(f"DeepScene label: no GT_color file for {image.name} (expected {stem}_mask.png in {gt_dir})")
            frames.append((stem, image, labels[stem]))
        if not frames:
            raise FileNotFoundError(f"DeepScene images: no .jpg / .png files in {rgb_dir}")
        super().__init__(frames, COLOURS, tolerance)
