"""Cityscapes-format stereo disparity and camera files (MMF's depth input, docs/papers/mmf.md#data).

Disparity PNGs are 16-bit: a stored value p > 0 means d = (p - 1) / 256 pixels, 0 means invalid
(returned as 0). Camera JSONs hold ``extrinsic.baseline`` (metres) and ``intrinsic.fx, fy, u0,
v0`` (pixels); they are returned flat, as the synthetic scenes' ``"camera"``.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from jaxanom.data.image_io import require_file
from jaxanom.errors import InputError


def read_disparity(path: Path) -> np.ndarray:
    """A Cityscapes disparity PNG -> (H, W) float32 pixels, 0 where invalid."""
    raw = cv2.imread(str(require_file(path, "disparity")), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise InputError("disparity", f": cannot decode {path} (corrupt or unsupported format)")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise InputError("disparity", f": expected a single-channel 16-bit PNG in {path}, got shape {raw.shape} "
                         f"dtype {raw.dtype}")
    value = raw.astype(np.float32)
    return np.where(raw > 0, (value - 1) / 256, 0).astype(np.float32)


def read_camera(path: Path) -> dict[str, float]:
    """A Cityscapes camera JSON -> ``{"baseline", "fx", "fy", "u0", "v0"}`` floats."""
    try:
        values = json.loads(require_file(path, "camera").read_text())
        return {"baseline": float(values["extrinsic"]["baseline"]),
                **{k: float(values["intrinsic"][k]) for k in ("fx", "fy", "u0", "v0")}}
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise InputError("camera", f": expected Cityscapes camera JSON with extrinsic.baseline and intrinsic "
                         f"fx, fy, u0, v0 in {path}, got an error: {error!r}") from None
