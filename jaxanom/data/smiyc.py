"""SegmentMeIfYouCan readers: RoadAnomaly21 (Anomaly Track) and RoadObstacle21 (Obstacle Track).

Layout of both tracks (``dataset_AnomalyTrack`` / ``dataset_ObstacleTrack``):
``<root>/images/<frame>.<jpg|webp|png>`` and ``<root>/labels_masks/<frame>_labels_semantic.png``
with 0 = in-distribution, 1 = anomaly / obstacle, 255 = void. Only the validation frames have
label masks (the test labels are held out), so the reader lists the frames that have one.
The tracks ship no depth: for MMF's RGB-D module pass ``depth_root``, a folder of
``<frame>_disparity.png`` in Cityscapes' 16-bit encoding (e.g. from a stereo or monocular
estimator); every labelled frame then needs one, and frames gain ``"disparity"`` (docs/papers/mmf.md#depth-input).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxanom.data.disparity import read_disparity
from jaxanom.data.frames import FrameReader
from jaxanom.data.image_io import ANOMALY_LABEL_VALUES, check_values, require_dir
from jaxanom.errors import InputError

_LABEL_SUFFIX = "_labels_semantic.png"
_IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".webp", ".png")


def _anomaly_labels(raw: np.ndarray, path: Path) -> np.ndarray:
    return check_values(raw, ANOMALY_LABEL_VALUES, path)


class SegmentMeIfYouCan(FrameReader):
    """``SegmentMeIfYouCan(root)[i]`` -> image, label 0 / 1 / 255, name; root is one track's folder.
    With ``depth_root``: also ``"disparity"`` (H, W) float32 pixels from user-supplied files."""

    def __init__(self, root: str | Path, depth_root: str | Path | None = None):
        image_dir = require_dir(Path(root) / "images", "SegmentMeIfYouCan images")
        label_dir = require_dir(Path(root) / "labels_masks", "SegmentMeIfYouCan label masks")
        labels = sorted(label_dir.glob(f"*{_LABEL_SUFFIX}"))
        if not labels:
            raise FileNotFoundError(f"SegmentMeIfYouCan label masks: no *{_LABEL_SUFFIX} in {label_dir}")
        frames = []
        for label in labels:
            name = label.name[: -len(_LABEL_SUFFIX)]
            images = [image_dir / f"{name}{ext}" for ext in _IMAGE_EXTENSIONS if (image_dir / f"{name}{ext}").is_file()]
            if not images:
                raise FileNotFoundError(f"SegmentMeIfYouCan image: no {name}{{{','.join(_IMAGE_EXTENSIONS)}}} "
                                        f"in {image_dir} for label {label}")
            if len(images) > 1:  # which one the labels belong to is not ours to guess
                raise ValueError(f"SegmentMeIfYouCan image: {' and '.join(map(str, images))} share the frame name "
                                 f"{name!r}; keep one image per frame")
            frames.append((name, images[0], label))
        super().__init__(frames, _anomaly_labels)
        self._disparity = []
        if depth_root is not None:
            depth_dir = require_dir(Path(depth_root), "SegmentMeIfYouCan depth (depth_root)")
            for name, _, _ in frames:
                path = depth_dir / f"{name}_disparity.png"
                if not path.is_file():
                    raise FileNotFoundError(f"SegmentMeIfYouCan depth: no {path.name} in {depth_dir}; the track has "
                                            f"no depth of its own: supply one disparity PNG per labelled frame")
                self._disparity.append(path)

    def __getitem__(self, index: int) -> dict:
        frame = super().__getitem__(index)
        if self._disparity:
            frame["disparity"] = read_disparity(self._disparity[index])
            if frame["disparity"].shape != frame["label"].shape:
                raise InputError("disparity", f": size {frame['disparity'].shape} of {self._disparity[index]} differs "
                                 f"from its image's {frame['label'].shape}")
        return frame


RoadAnomaly21 = SegmentMeIfYouCan
RoadObstacle21 = SegmentMeIfYouCan
