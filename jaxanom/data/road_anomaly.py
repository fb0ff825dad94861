"""Road Anomaly reader (Lis et al., ICCV 2019), in the dataset's own layout.

Layout: ``<root>/frame_list.json`` (a JSON list of image file names), ``<root>/frames/<name>.jpg``
and ``<root>/frames/<name>.labels/labels_semantic.png`` with 0 = background, 2 = anomaly; the
reader returns 0 / 1 labels (the dataset has no void).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from jaxanom.data.frames import FrameReader
from jaxanom.data.image_io import check_values, require_dir, require_file


def _anomaly_labels(raw: np.ndarray, path: Path) -> np.ndarray:
    return (check_values(raw, (0, 2), path) == 2).astype(np.uint8)


class RoadAnomaly(FrameReader):
    """``RoadAnomaly(root)[i]`` -> image, label 0 / 1, name (image file name without extension)."""

    def __init__(self, root: str | Path):
        frame_dir = require_dir(Path(root) / "frames", "Road Anomaly frames")
        list_file = require_file(Path(root) / "frame_list.json", "Road Anomaly frame list")
        try:
            names = json.loads(list_file.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise ValueError(f"Road Anomaly frame list: {list_file} is not valid JSON ({error})") from None
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise ValueError(f"Road Anomaly frame list: expected a non-empty JSON list of file names in {list_file}")
        frames = []
        for file_name in names:
            stem = Path(file_name).stem
            image = require_file(frame_dir / file_name, "Road Anomaly image")
            label = require_file(frame_dir / f"{stem}.labels" / "labels_semantic.png", "Road Anomaly label")
            frames.append((stem, image, label))
        super().__init__(frames, _anomaly_labels)
