"""The random-access contract every dataset reader follows.

A reader is a sequence of frames: ``len(reader)`` and ``reader[i]`` -> ``{"image": (H, W, 3) uint8
RGB, "label": (H, W) uint8, "name": str}``. It finds its files when built (FileNotFoundError naming
the folder or file that is missing) and decodes one frame per ``__getitem__`` (ValueError naming a
corrupt file or labels outside the dataset's allowed values), so grain can read it in any order.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from jaxanom.data.image_io import check_same_size, read_label, read_rgb


class FrameReader:
    """Frames given as ``(name, image path, label path)``; ``decode_label`` maps raw label files.

    ``decode_label(raw (H, W) uint8, label path) -> (H, W) uint8`` validates and maps values.
    """

    def __init__(self, frames: list[tuple[str, Path, Path]],
                 decode_label: Callable[[np.ndarray, Path], np.ndarray]):
        self.frames = frames
        self._decode_label = decode_label

    def __len__(self) -> int:
        return len(self.frames)

    def read_image(self, index: int) -> np.ndarray:
        return read_rgb(self.frames[index][1])

    def __getitem__(self, index: int) -> dict[str, Any]:
        if not 0 <= index < len(self.frames):
            raise IndexError(f"index {index} out of range for {len(self.frames)} frames")
        name, _, label_path = self.frames[index]
        image = self.read_image(index)
        label = self._decode_label(read_label(label_path), label_path)
        check_same_size(image, label, label_path)
        return {"image": image, "label": label, "name": name}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({len(self)} frames)"


class FirstFrames:
    """The first ``count`` frames of a random-access source (all of them if it has fewer)."""

    def __init__(self, source, count: int):
        if count < 1:
            raise ValueError(f"count: expected >= 1, got {count}")
        self.source, self.count = source, min(count, len(source))

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int) -> dict[str, Any]:
        if not 0 <= index < self.count:
            raise IndexError(f"index {index} out of range for {self.count} frames")
        return self.source[index]


class Resized:
    """The frames of a random-access source resized to ``height`` x ``width``: the image bilinearly
    (OpenCV's ``INTER_LINEAR``), the label (if any) by nearest neighbour, so its values stay in their set."""

    def __init__(self, source, height: int, width: int):
        if height < 1 or width < 1:
            raise ValueError(f"height, width: expected >= 1, got {height} x {width}")
        self.source, self.size = source, (int(width), int(height))

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, index: int) -> dict[str, Any]:
        import cv2

        frame = dict(self.source[index])
        frame["image"] = cv2.resize(frame["image"], self.size, interpolation=cv2.INTER_LINEAR)
        if "label" in frame:
            frame["label"] = cv2.resize(frame["label"], self.size, interpolation=cv2.INTER_NEAREST)
        return frame

