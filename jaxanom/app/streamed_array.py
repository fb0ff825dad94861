"""A .npy / .npz array read one image at a time (``jaxanom score``'s logits and labels)."""
from __future__ import annotations

import contextlib
import zipfile
import zlib
from pathlib import Path

from jaxanom.errors import InputError

# what NumPy and zipfile raise for empty, truncated or damaged .npy / .npz files
_UNREADABLE = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error)


class StreamedArray:
    """An array in a .npy file, or called ``name`` in a .npz file, read one image (leading index) at a time.

    Both are read sequentially, one image's bytes after the other (a .npz member is decompressed
    as it goes), so resident memory holds one image whatever the file's size: the pages of a
    memory map would count as resident once touched. An array stored in Fortran order is
    memory-mapped (.npy) or read whole (.npz). Reading errors (empty, truncated or damaged
    files) become an InputError naming the argument ``name``.
    """

    def __init__(self, path: str, name: str):
        import numpy as np

        self.path, self.name = Path(path), name
        if not self.path.is_file():
            raise InputError(name, f"{path}: no such file")
        self._whole = None
        with self._reading():
            with open(self.path, "rb") as f:
                self._member = f"{name}.npy" if f.read(4) == b"PK\x03\x04" else None  # np.load's test for .npz
            if self._member is not None:
                with zipfile.ZipFile(self.path) as archive:
                    found = [m[:-4] for m in archive.namelist() if m.endswith(".npy")]
                    if name not in found:
                        raise InputError(name, f"{path}: expected an array named {name!r}, found {found}")
                    stored = archive.getinfo(self._member).file_size
            else:
                stored = self.path.stat().st_size
            with self._open() as f:
                self.shape, fortran, self.dtype = _read_header(f)
                needed = f.tell() + int(np.prod(self.shape, dtype=np.int64)) * self.dtype.itemsize
            if stored < needed:
                raise EOFError(f"holds {stored} bytes, its header announces {needed}")
            if fortran and self._member is None:
                self._whole = np.load(self.path, mmap_mode="r", allow_pickle=False)
            elif fortran:
                with np.load(self.path, allow_pickle=False) as data:
                    self._whole = data[name]
        self.ndim = len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __iter__(self):
        """The images ``array[i]`` in order, each an in-memory ndarray."""
        import numpy as np

        with self._reading():
            if self._whole is not None:
                for index in range(len(self)):
                    yield np.array(self._whole[index])
                return
            size = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize
            with self._open() as f:
                _read_header(f)
                for _ in range(len(self)):
                    data = f.read(size)
                    if len(data) != size:
                        raise EOFError("the array ends early")
                    yield np.frombuffer(data, self.dtype).reshape(self.shape[1:])

    @contextlib.contextmanager
    def _open(self):
        """The .npy stream: the file, or the member of the .npz file."""
        if self._member is None:
            with open(self.path, "rb") as f:
                yield f
        else:
            with zipfile.ZipFile(self.path) as archive, archive.open(self._member) as f:
                yield f

    def _reading(self):
        return _converted_errors(self.name, f"{self.path}: not a readable .npy/.npz file")


def _read_header(f):
    """``(shape, fortran_order, dtype)`` of the .npy stream ``f``, refusing object arrays."""
    import numpy as np

    major, _ = np.lib.format.read_magic(f)
    read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
    shape, fortran, dtype = read(f)
    if dtype.hasobject:
        raise ValueError("it holds Python objects (pickles are not read)")
    return shape, fortran, dtype


@contextlib.contextmanager
def _converted_errors(argument: str, what: str):
    """Reading errors inside the block become an InputError of ``argument``: ``what (error)``."""
    try:
        yield
    except InputError:
        raise
    except _UNREADABLE as error:
        raise InputError(argument, f"{what} ({type(error).__name__}: {error})") from None
