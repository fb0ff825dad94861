"""Cityscapes reader (official layout), fine labels mapped to the 19 trainIds.

Layout: ``<root>/leftImg8bit/<split>/<city>/<city>_<seq>_<frame>_leftImg8bit.png`` and
``<root>/gtFine/<split>/<city>/<city>_<seq>_<frame>_gtFine_labelIds.png``; with
``with_disparity=True`` also ``<root>/disparity/<split>/<city>/<name>_disparity.png`` and
``<root>/camera/<split>/<city>/<name>_camera.json`` (MMF's depth input).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxanom.data.cityscapes_labels import LABEL_ID_TO_TRAIN_ID, NUM_LABEL_IDS
from jaxanom.data.disparity import read_camera, read_disparity
from jaxanom.data.frames import FrameReader
from jaxanom.data.image_io import check_values, require_dir, require_file
from jaxanom.errors import InputError

_IMAGE_SUFFIX = "_leftImg8bit.png"


def _train_ids(raw: np.ndarray, path: Path) -> np.ndarray:
    return LABEL_ID_TO_TRAIN_ID[check_values(raw, range(NUM_LABEL_IDS), path)]


class Cityscapes(FrameReader):
    """``Cityscapes(root, split)[i]`` -> image, trainId label (255 = ignore), name ``<city>_<seq>_<frame>``;
    with ``with_disparity``: ``"disparity"`` (H, W) float32 pixels (0 invalid) and ``"camera"``.
    ``with_labels=False``: image and name only, and ``gtFine/`` need not exist (e.g. for statistics
    of a network's predictions)."""

    def __init__(self, root: str | Path, split: str = "train", with_disparity: bool = False,
                 with_labels: bool = True):
        image_dir = require_dir(Path(root) / "leftImg8bit" / split, "Cityscapes images")
        label_dir = require_dir(Path(root) / "gtFine" / split, "Cityscapes fine labels") if with_labels else None
        images = sorted(image_dir.glob(f"*/*{_IMAGE_SUFFIX}"))
        if not images:
            raise FileNotFoundError(f"Cityscapes images: no <city>/*{_IMAGE_SUFFIX} in {image_dir}")
        frames = []
        for image in images:
            name = image.name[: -len(_IMAGE_SUFFIX)]
            label = None if label_dir is None else require_file(
                label_dir / image.parent.name / f"{name}_gtFine_labelIds.png", "Cityscapes label")
            frames.append((name, image, label))
        super().__init__(frames, _train_ids)
        self.with_labels = with_labels
        self._stereo = []
        if with_disparity:
            for name, image, _ in frames:
                city = image.parent.name
                self._stereo.append((
                    require_file(Path(root) / "disparity" / split / city / f"{name}_disparity.png", "Cityscapes disparity"),
                    require_file(Path(root) / "camera" / split / city / f"{name}_camera.json", "Cityscapes camera")))

    def __getitem__(self, index: int) -> dict:
        if self.with_labels:
            frame = super().__getitem__(index)
        elif 0 <= index < len(self.frames):
            frame = {"image": self.read_image(index), "name": self.frames[index][0]}
        else:
            raise IndexError(f"index {index} out of range for {len(self.frames)} frames")
        if self._stereo:
            disparity_path, camera_path = self._stereo[index]
            frame["disparity"] = read_disparity(disparity_path)
            if frame["disparity"].shape != frame["image"].shape[:2]:
                raise InputError("disparity", f": size {frame['disparity'].shape} of {disparity_path} differs from "
                                 f"its image's {frame['image'].shape[:2]}")
            frame["camera"] = read_camera(camera_path)
        return frame
