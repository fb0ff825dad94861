"""Fishyscapes validation readers: Lost & Found and Static, from the official release files.

Fishyscapes publishes only masks (and, for Static, colour overlays); the images come from the
base datasets, so each reader takes two folders (layout of the official zips and base datasets):

- Lost & Found: ``fishyscapes_lostandfound.zip`` extracted to ``masks_dir``, holding
  ``<fsid>_<lafid>_labels.png`` (e.g. ``0000_04_Maurener_Weg_8_000000_000030_labels.png``);
  the image is ``<lostandfound_root>/leftImg8bit/<train|test>/<city>/<lafid>_leftImg8bit.png``.
- Static: ``fs_val_v3.zip`` (or v1 / v2) extracted to ``masks_dir``, holding
  ``<fsid>_<csid>_labels.png`` and an overlay ``<fsid>_..._rgb.npz`` whose array ``"rgb"``
  (H, W, 3, integers) is added to ``<cityscapes_root>/leftImg8bit/val/<city>/<csid>_leftImg8bit.png``
  and clipped to 0..255 (as the benchmark's own loader does).

Masks hold 0 = in-distribution, 1 = anomaly, 255 = void.
"""
from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np

from jaxanom.data.frames import FrameReader
from jaxanom.data.image_io import ANOMALY_LABEL_VALUES, check_values, read_rgb, require_dir, require_file
from jaxanom.errors import InputError

_MASK_NAME = re.compile(r"^([0-9]+)_(.+)_labels\.png$")
_IMAGE_SUFFIX = "_leftImg8bit.png"


def _anomaly_labels(raw: np.ndarray, path: Path) -> np.ndarray:
    return check_values(raw, ANOMALY_LABEL_VALUES, path)


def _masks(masks_dir: Path, what: str) -> list[tuple[str, str, Path]]:
    """``(fsid, base image id, mask path)`` for every ``<fsid>_<id>_labels.png`` in ``masks_dir``."""
    masks = [(m.group(1), m.group(2), p) for p in sorted(require_dir(masks_dir, what).iterdir())
             if (m := _MASK_NAME.match(p.name))]
    if not masks:
        raise FileNotFoundError(f"{what}: no <fsid>_<image id>_labels.png in {masks_dir}")
    return masks


def _base_images(image_root: Path, splits: tuple[str, ...], what: str) -> dict[str, Path]:
    """``{image id: path}`` of ``<image_root>/<split>/<city>/<id>_leftImg8bit.png`` over ``splits``."""
    found = {}
    for split in splits:
        if (image_root / split).is_dir():
            found.update({p.name[: -len(_IMAGE_SUFFIX)]: p for p in (image_root / split).glob(f"*/*{_IMAGE_SUFFIX}")})
    if not found:
        raise FileNotFoundError(f"{what}: no <split>/<city>/*{_IMAGE_SUFFIX} for splits {splits} in {image_root}")
    return found


def _pair(masks, images: dict[str, Path], what: str, image_root: Path) -> list[tuple[str, Path, Path]]:
    frames = []
    for fsid, image_id, mask in masks:
        if image_id not in images:
            raise FileNotFoundError(
                f"{what}: image {image_id}{_IMAGE_SUFFIX} for mask {mask} not found under {image_root}")
        frames.append((fsid, images[image_id], mask))
    return frames


class FishyscapesLostAndFound(FrameReader):
    """``FishyscapesLostAndFound(masks_dir, lostandfound_root)[i]`` -> image, label 0/1/255, name fsid."""

    def __init__(self, masks_dir: str | Path, lostandfound_root: str | Path):
        image_root = require_dir(Path(lostandfound_root) / "leftImg8bit", "Lost & Found images")
        masks = _masks(Path(masks_dir), "Fishyscapes Lost & Found masks")
        images = _base_images(image_root, ("test", "train"), "Lost & Found images")
        super().__init__(_pair(masks, images, "Lost & Found images", image_root), _anomaly_labels)


class FishyscapesStatic(FrameReader):
    """``FishyscapesStatic(masks_dir, cityscapes_root)[i]`` -> blended image, label 0/1/255, name fsid."""

    def __init__(self, masks_dir: str | Path, cityscapes_root: str | Path):
        image_root = require_dir(Path(cityscapes_root) / "leftImg8bit", "Cityscapes images")
        masks = _masks(Path(masks_dir), "Fishyscapes Static masks")
        images = _base_images(image_root, ("val",), "Cityscapes images")
        files = sorted(p.name for p in Path(masks_dir).iterdir())
        self.overlays = []
        for fsid, _, _ in masks:
            overlay = [f for f in files if f.startswith(f"{fsid}_") and f.endswith("rgb.npz")]
            if not overlay:
                raise FileNotFoundError(f"Fishyscapes Static overlay: no {fsid}_*rgb.npz in {masks_dir}")
            self.overlays.append(Path(masks_dir) / overlay[0])
        super().__init__(_pair(masks, images, "Cityscapes images", image_root), _anomaly_labels)

    def read_image(self, index: int) -> np.ndarray:
        base = read_rgb(self.frames[index][1])
        path = require_file(self.overlays[index], "Fishyscapes Static overlay")
        try:
            with np.load(path, allow_pickle=False) as archive:
                overlay = archive["rgb"]
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
            raise InputError("overlay", f": cannot read array 'rgb' from {path} ({error})") from None
        if overlay.shape != base.shape:
            raise InputError("overlay", f": shape {overlay.shape} of {path} "
                             f"differs from its image's {base.shape}")
        return np.clip(base.astype(np.int32) + overlay.astype(np.int32), 0, 255).astype(np.uint8)
