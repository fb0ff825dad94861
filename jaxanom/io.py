"""Atomic file writes: a crash never leaves a half-written result behind.

Every writer puts the bytes in a temporary file beside the target and renames it into place
(``os.replace`` is atomic on POSIX and Windows), so readers see the old file or the new one.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically, creating parent folders; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_json_atomic(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as indented JSON, atomically."""
    return write_bytes_atomic(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode())


def write_png_atomic(path: str | os.PathLike, rgb) -> Path:
    """Write an RGB (H, W, 3) or grey (H, W) uint8 array as PNG, atomically."""
    import cv2
    import numpy as np

    array = np.asarray(rgb)
    if array.dtype != np.uint8 or array.ndim not in (2, 3):
        raise ValueError(f"rgb: expected uint8 (H, W) or (H, W, 3), got {array.dtype} {array.shape}")
    bgr = array[..., ::-1] if array.ndim == 3 else array
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(bgr))
    if not ok:
        raise ValueError(f"rgb: OpenCV could not encode an array of shape {array.shape} as PNG")
    return write_bytes_atomic(path, encoded.tobytes())
