"""Reading images and label masks from disk with errors that name the file.

``cv2.imread`` returns ``None`` for missing or undecodable files instead of raising, and fills
the missing part of a truncated JPEG with grey (libjpeg only warns). Every reader goes through
these functions, which read the bytes and decode them strictly (``cv2.imdecode`` fails on a
truncated stream; a JPEG must also hold its end-of-image marker after the scan), so that a bad
file gives a ``FileNotFoundError`` or an ``InputError`` (a ``ValueError``) with its path.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from jaxanom.errors import InputError

ANOMALY_LABEL_VALUES = (0, 1, 255)


def require_dir(path: Path, what: str) -> Path:
    """``path`` as a Path, or FileNotFoundError naming ``what`` it should hold."""
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"{what}: folder {path} does not exist")
    return path


def require_file(path: Path, what: str) -> Path:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what}: file {path} does not exist")
    return path


def _decode(path: Path, what: str, flags: int) -> np.ndarray:
    """Decode the file strictly: ValueError naming it when truncated, corrupt or unsupported."""
    data = require_file(path, what).read_bytes()
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None
    except cv2.error as error:  # OpenCV refuses images above its pixel limit (2^30 by default) this way
        reason = "more pixels than OpenCV decodes (OPENCV_IO_MAX_IMAGE_PIXELS, 2^30 by default)" if (
            "CV_IO_MAX_IMAGE_PIXELS" in str(error)) else str(error).strip().splitlines()[-1]
        raise InputError(what, f": cannot decode {path} ({reason})") from None
    jpeg = data[:2] == b"\xff\xd8"
    if image is None or (jpeg and data.find(b"\xff\xd9", data.find(b"\xff\xda")) < 0):
        raise InputError(what, f": cannot decode {path} (truncated, corrupt or unsupported format)")
    return image


def read_rgb(path: Path) -> np.ndarray:
    """An image file -> (H, W, 3) uint8 RGB."""
    return cv2.cvtColor(_decode(path, "image", cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def read_label(path: Path) -> np.ndarray:
    """A single-channel 8-bit label PNG -> (H, W) uint8, values unchanged."""
    label = _decode(path, "label", cv2.IMREAD_UNCHANGED)
    if label.ndim != 2 or label.dtype != np.uint8:
        raise InputError("label", f": expected a single-channel 8-bit image in {path}, "
                         f"got shape {label.shape} dtype {label.dtype}")
    return label


def check_values(label: np.ndarray, allowed, path: Path) -> np.ndarray:
    """Return ``label`` if all its values are in ``allowed``, else ValueError naming the file."""
    bad = np.setdiff1d(np.unique(label), np.asarray(allowed))
    if bad.size:
        raise InputError("label", f": expected values in {tuple(allowed)} in {path}, got {bad.tolist()}")
    return label


def check_same_size(image: np.ndarray, label: np.ndarray, path: Path) -> None:
    if image.shape[:2] != label.shape:
        raise InputError("label", f": size {label.shape} of {path} differs from its image's {image.shape[:2]}")
