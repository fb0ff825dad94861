"""Training augmentations of the papers, on one record, with an explicit NumPy generator.

A record is a dict with ``"image"`` (H, W, 3) uint8 and ``"label"`` (H, W) uint8, optionally
``"depth"`` (H, W) float32. Geometric transforms move all of them together: the image is
resampled bilinearly, label and depth by nearest neighbour (so label values stay in their set);
padding is 0 for the image and depth and the ignore label 255 for the label.

``normalize`` (ImageNet mean / std) is plain arithmetic and works on NumPy and JAX arrays alike,
so the model side can call it inside ``jit``.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np

IGNORE_INDEX = 255
IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32)
IMAGENET_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32)
_PAD_VALUE = {"image": 0, "label": IGNORE_INDEX, "depth": 0}


def normalize(image):
    """uint8 RGB (..., 3) -> float32 ``(image / 255 - mean) / std`` with ImageNet statistics."""
    return (image.astype("float32") / 255.0 - IMAGENET_MEAN) / IMAGENET_STD


def _pixel_keys(record: dict) -> list[str]:
    return [key for key in _PAD_VALUE if key in record]


def rescale(record: dict[str, Any], scale: float) -> dict[str, Any]:
    """Resize by ``scale`` (output size ``round(scale * H), round(scale * W)``, at least 1)."""
    height, width = record["label"].shape
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    out = dict(record)
    for key in _pixel_keys(record):
        mode = cv2.INTER_LINEAR if key == "image" else cv2.INTER_NEAREST
        out[key] = cv2.resize(record[key], size, interpolation=mode)
    return out


def pad_and_crop(record: dict[str, Any], crop_hw: tuple[int, int], top: int, left: int) -> dict[str, Any]:
    """Pad bottom / right up to ``crop_hw`` (image 0, label 255), then take the crop at (top, left)."""
    crop_h, crop_w = crop_hw
    height, width = record["label"].shape
    pad_h, pad_w = max(crop_h - height, 0), max(crop_w - width, 0)
    out = dict(record)
    for key in _pixel_keys(record):
        value = record[key]
        if pad_h or pad_w:
            widths = ((0, pad_h), (0, pad_w)) + ((0, 0),) * (value.ndim - 2)
            value = np.pad(value, widths, constant_values=_PAD_VALUE[key])
        out[key] = np.ascontiguousarray(value[top:top + crop_h, left:left + crop_w])
    return out


def hflip(record: dict[str, Any]) -> dict[str, Any]:
    """Mirror left-right."""
    out = dict(record)
    for key in _pixel_keys(record):
        out[key] = np.ascontiguousarray(record[key][:, ::-1])
    return out


def color_jitter(image: np.ndarray, brightness: float, contrast: float, saturation: float) -> np.ndarray:
    """Multiply brightness, contrast (around the mean grey) and saturation (around each pixel's grey)."""
    x = image.astype(np.float32) * brightness
    grey = x @ np.array([0.299, 0.587, 0.114], np.float32)
    x = (x - grey.mean()) * contrast + grey.mean()
    grey = x @ np.array([0.299, 0.587, 0.114], np.float32)
    x = (x - grey[..., None]) * saturation + grey[..., None]
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


@dataclasses.dataclass(frozen=True)
class Augment:
    """Random scale, pad + random crop, horizontal flip, colour jitter (the papers' recipe).

    Call with ``(record, rng)``: this is a ``grain`` random map, one generator per record.
    ``jitter`` is the half-width of the uniform factor range for brightness, contrast, saturation.
    """

    crop_hw: tuple[int, int] = (768, 768)
    scale_range: tuple[float, float] = (0.5, 2.0)
    flip_prob: float = 0.5
    jitter: float = 0.25

    def __post_init__(self):
        if min(self.crop_hw) < 1 or not 0 < self.scale_range[0] <= self.scale_range[1]:
            raise ValueError(f"crop_hw, scale_range: expected positive sizes and 0 < low <= high, "
                             f"got {self.crop_hw}, {self.scale_range}")

    def __call__(self, record: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        record = {key: record[key] for key in _pixel_keys(record)}
        record = rescale(record, rng.uniform(*self.scale_range))
        height, width = record["label"].shape
        top = int(rng.integers(0, max(height - self.crop_hw[0], 0) + 1))
        left = int(rng.integers(0, max(width - self.crop_hw[1], 0) + 1))
        record = pad_and_crop(record, self.crop_hw, top, left)
        if rng.random() < self.flip_prob:
            record = hflip(record)
        factors = rng.uniform(1 - self.jitter, 1 + self.jitter, 3)
        record["image"] = color_jitter(record["image"], *factors)
        return record
