"""Atomic file writes: a crash never leaves a half-written result behind.

Every writer puts the bytes in a temporary file beside the target and renames it into place
(``os.replace`` is atomic on POSIX and Windows), so readers see the old file or the new one.
The file gets the permissions of a plain ``open(path, "w")``, 0o666 less the umask (``mkstemp``
alone would leave it 0o600, unreadable to colleagues).
"""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically, creating parent folders; returns the path."""
    return write_with_atomic(path, lambda tmp: write_synced(tmp, data))


def write_with_atomic(path: str | os.PathLike, write) -> Path:
    """``write(temporary_path)`` fills a temporary file beside ``path`` (any writer that takes a
    file name, e.g. h5py), which is then renamed to ``path``; removed if ``write`` raises."""
    path = Path(path)
    tmp = write_temporary(path, write)
    try:
        os.replace(tmp, path)
    except BaseException as error:
        Path(tmp).unlink(missing_ok=True)
        _name_file(error, path)
        raise
    return path


def write_temporary(path: str | os.PathLike, write) -> str:
    """The first half of an atomic write: ``write(temporary_path)`` fills a temporary file beside
    ``path`` (``.<name>.*.tmp``), whose name is returned; ``os.replace(it, path)`` completes the
    write (so several files can be prepared at once and published in a chosen order). Removed if
    ``write`` raises."""
    path = Path(path)
    fd, tmp = _temporary(path)
    os.close(fd)
    try:
        write(tmp)
    except BaseException as error:
        Path(tmp).unlink(missing_ok=True)
        _name_file(error, path)
        raise
    return tmp


def write_synced(path: str, data: bytes) -> None:
    """Write ``data`` to the file ``path`` and wait until it is on the disk."""
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _name_file(error: BaseException, path: Path) -> None:
    """Give an OSError without a file name (a full disk, as ``write`` and ``fsync`` report it) ``path``,
    so that its message says where writing failed."""
    if isinstance(error, OSError) and error.filename is None:
        error.filename = str(path)


def _temporary(path: Path) -> tuple[int, str]:
    """An open temporary file beside ``path`` (parents created) with the umask's permissions."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.fchmod(fd, 0o666 & ~_umask())
    return fd, tmp


def _umask() -> int:
    """The process's umask (reading it means setting it; set straight back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_json_atomic(path: str | os.PathLike, obj: Any, *, allow_nan: bool = True) -> Path:
    """Write ``obj`` as indented JSON, atomically; ``allow_nan=False``: ValueError, before anything is
    written, where ``obj`` holds NaN or infinity (which JSON has no word for)."""
    return write_bytes_atomic(path, (json.dumps(obj, indent=2, sort_keys=True, allow_nan=allow_nan) + "\n").encode())


def jsonable(value):
    """``value`` (e.g. an evaluator's finalized metrics) as JSON values: NumPy scalars and arrays as
    numbers and lists, in dicts (keys as strings), lists and tuples; other values as they are."""
    import numpy as np

    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    if isinstance(value, dict):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(item) for item in value]
    return value


def write_png_atomic(path: str | os.PathLike, rgb) -> Path:
    """Write an RGB (H, W, 3) or grey (H, W) uint8 array as PNG, atomically."""
    return write_bytes_atomic(path, png_bytes(rgb))


def png_bytes(rgb) -> bytes:
    """An RGB (H, W, 3) or grey (H, W) uint8 array encoded as PNG."""
    import cv2
    import numpy as np

    array = np.asarray(rgb)
    if array.dtype != np.uint8 or array.ndim not in (2, 3):
        raise ValueError(f"rgb: expected uint8 (H, W) or (H, W, 3), got {array.dtype} {array.shape}")
    bgr = array[..., ::-1] if array.ndim == 3 else array
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(bgr))
    if not ok:
        raise ValueError(f"rgb: OpenCV could not encode an array of shape {array.shape} as PNG")
    return encoded.tobytes()


class NpyWriter:
    """An ``.npy`` file of known ``shape`` and ``dtype`` written one leading-axis slice at a time.

    Slices go to a temporary file as they come (nothing is held in memory); ``close()`` renames
    it to ``path`` once all ``shape[0]`` slices are written, and leaving a ``with`` block by an
    exception removes it, so ``path`` holds a complete array or nothing.
    """

    def __init__(self, path: str | os.PathLike, shape: tuple[int, ...], dtype):
        import numpy as np

        self.path, self.shape, self.dtype = Path(path), tuple(int(n) for n in shape), np.dtype(dtype)
        self.written = 0
        fd, self._tmp = _temporary(self.path)
        self._file = os.fdopen(fd, "wb")
        header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False, "shape": self.shape}
        np.lib.format.write_array_header_1_0(self._file, header)

    def write(self, rows) -> None:
        """Append one slice of shape ``shape[1:]``."""
        import numpy as np

        rows = np.ascontiguousarray(rows, self.dtype)
        if rows.shape != self.shape[1:] or self.written >= self.shape[0]:
            raise ValueError(f"rows: expected slice {self.written} of shape {self.shape[1:]} for "
                             f"{self.path} of shape {self.shape}, got {rows.shape}")
        try:
            self._file.write(rows.tobytes())
        except OSError as error:
            _name_file(error, self.path)
            raise
        self.written += 1

    def close(self) -> Path:
        """Flush and move the complete file into place; ValueError if slices are missing."""
        if self.written != self.shape[0]:
            self.abort()
            raise ValueError(f"{self.path}: expected {self.shape[0]} slices, got {self.written}")
        try:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            os.replace(self._tmp, self.path)
        except OSError as error:
            self.abort()
            _name_file(error, self.path)
            raise
        return self.path

    def abort(self) -> None:
        """Drop the temporary file."""
        with contextlib.suppress(OSError):  # closing flushes: the full disk that made the writer give up
            self._file.close()
        Path(self._tmp).unlink(missing_ok=True)

    def __enter__(self) -> "NpyWriter":
        return self

    def __exit__(self, kind, *exc) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()
