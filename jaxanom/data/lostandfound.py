"""Lost and Found (Pinggera et al. 2016), the full test set MMF evaluates on, Cityscapes-like layout.

``<root>/leftImg8bit/<split>/<sequence>/<name>_leftImg8bit.png``,
``<root>/gtCoarse/<split>/<sequence>/<name>_gtCoarse_labelIds.png``,
``<root>/disparity/<split>/<sequence>/<name>_disparity.png`` and (optional)
``<root>/camera/<split>/<sequence>/<name>_camera.json``. Labels (docs/papers/mmf.md#data): free space 1 -> 0,
obstacles (ids >= 2) -> 1, unlabelled 0 -> 255; the road ROI (``"roi"``) is free space and
obstacles. File names follow the official archives' scheme as documented; they were not checked
against a downloaded archive here.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxanom.data.disparity import read_camera, read_disparity
from jaxanom.data.frames import FrameReader
from jaxanom.data.image_io import require_dir, require_file
from jaxanom.errors import InputError

_IMAGE_SUFFIX = "_leftImg8bit.png"


def _anomaly_labels(raw: np.ndarray, path: Path) -> np.ndarray:
    return np.where(raw == 0, 255, np.where(raw == 1, 0, 1)).astype(np.uint8)


class LostAndFound(FrameReader):
    """``LostAndFound(root, split)[i]`` -> image, label 0/1/255, ``"roi"`` bool, ``"disparity"``
    (float32 pixels, 0 invalid), ``"camera"`` (when the camera file exists), name."""

    def __init__(self, root: str | Path, split: str = "test"):
        root = Path(root)
        image_dir = require_dir(root / "leftImg8bit" / split, "Lost and Found images")
        label_dir = require_dir(root / "gtCoarse" / split, "Lost and Found labels")
        disparity_dir = require_dir(root / "disparity" / split, "Lost and Found disparity")
        images = sorted(image_dir.glob(f"*/*{_IMAGE_SUFFIX}"))
        if not images:
            raise FileNotFoundError(f"Lost and Found images: no <sequence>/*{_IMAGE_SUFFIX} in {image_dir}")
        frames, self._stereo = [], []
        for image in images:
            name, sequence = image.name[: -len(_IMAGE_SUFFIX)], image.parent.name
            label = require_file(label_dir / sequence / f"{name}_gtCoarse_labelIds.png", "Lost and Found label")
            frames.append((name, image, label))
            self._stereo.append((
                require_file(disparity_dir / sequence / f"{name}_disparity.png", "Lost and Found disparity"),
                root / "camera" / split / sequence / f"{name}_camera.json"))
        super().__init__(frames, _anomaly_labels)

    def __getitem__(self, index: int) -> dict:
        frame = super().__getitem__(index)
        frame["roi"] = frame["label"] != 255
        disparity_path, camera_path = self._stereo[index]
        frame["disparity"] = read_disparity(disparity_path)
        if frame["disparity"].shape != frame["label"].shape:
            raise InputError("disparity", f": size {frame['disparity'].shape} of {disparity_path} differs from its "
                             f"image's {frame['label'].shape}")
        if camera_path.is_file():
            frame["camera"] = read_camera(camera_path)
        return frame
