"""The 19 Cityscapes training classes: names, official colours, and the labelId -> trainId table.

Facts from the official Cityscapes label definition (``cityscapesscripts/helpers/labels.py``):
34 label ids (0..33), of which 19 are trained on (trainIds 0..18); the others map to 255 (ignore).
"""
from __future__ import annotations

import numpy as np

IGNORE_INDEX = 255
NUM_CLASSES = 19

CLASS_NAMES: tuple[str, ...] = (
    "road", "sidewalk", "building", "wall", "fence", "pole", "traffic light", "traffic sign",
    "vegetation", "terrain", "sky", "person", "rider", "car", "truck", "bus", "train",
    "motorcycle", "bicycle",
)

# Official RGB colour of each trainId, (19, 3) uint8.
CLASS_COLORS = np.array(
    [
        (128, 64, 128), (244, 35, 232), (70, 70, 70), (102, 102, 156), (190, 153, 153),
        (153, 153, 153), (250, 170, 30), (220, 220, 0), (107, 142, 35), (152, 251, 152),
        (70, 130, 180), (220, 20, 60), (255, 0, 0), (0, 0, 142), (0, 0, 70), (0, 60, 100),
        (0, 80, 100), (0, 0, 230), (119, 11, 32),
    ],
    dtype=np.uint8,
)

# labelId -> trainId for the labelIds 0..33 that trained classes come from; all others are 255.
_TRAIN_ID_OF_LABEL_ID = {
    7: 0, 8: 1, 11: 2, 12: 3, 13: 4, 17: 5, 19: 6, 20: 7, 21: 8, 22: 9, 23: 10, 24: 11, 25: 12,
    26: 13, 27: 14, 28: 15, 31: 16, 32: 17, 33: 18,
}
NUM_LABEL_IDS = 34

# Lookup table over all 256 uint8 values: ``LABEL_ID_TO_TRAIN_ID[label_ids]`` gives trainIds.
LABEL_ID_TO_TRAIN_ID = np.full(256, IGNORE_INDEX, dtype=np.uint8)
for _label_id, _train_id in _TRAIN_ID_OF_LABEL_ID.items():
    LABEL_ID_TO_TRAIN_ID[_label_id] = _train_id
del _label_id, _train_id
