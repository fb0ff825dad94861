"""What every command shares: the error type, output folders, flags and array loading."""
from __future__ import annotations

import argparse
import contextlib
import glob
import os
import shutil
import socket
import sys
import zipfile
import zlib
from pathlib import Path

DEFAULT_METHODS = "msp,max_logit,entropy,energy,sml,sml_post"
CLAIM = ".jaxanom-claim"  # marker of a command writing into a folder (or beside a file), removed at its end
_claimed: list[Path] = []
_outputs: list[tuple[Path, set[str] | None]] = []  # (out folder, its subfolders when claimed, None if new)
# what NumPy and zipfile raise for empty, truncated or damaged .npy / .npz files
_UNREADABLE = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error)


class CommandError(Exception):
    """Bad input to a command: printed as one line, exit status 2."""


def positive_int(text: str) -> int:
    """argparse type of counts that must be >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def nonnegative_int(text: str) -> int:
    """argparse type of counts that may be 0."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    return value


def method_list(text: str) -> str:
    """argparse type of ``--methods``: comma-separated names, none of them empty (so ``""`` is not
    read as "the default list")."""
    if not all(name.strip() for name in text.split(",")):
        raise argparse.ArgumentTypeError(f"expected comma-separated method names, got {text!r}")
    return text


def size_hw(text: str | None, flag: str = "--size") -> tuple[int, int] | None:
    """``(H, W)`` from ``HxW`` (e.g. ``512x1024``), or None for None."""
    if text is None:
        return None
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise CommandError(f"{flag}: expected HEIGHTxWIDTH with positive integers (e.g. 512x1024), got {text!r}")
    return int(parts[0]), int(parts[1])


def add_config(parser, config_help: str | None = None) -> None:
    """``--set NAME=VALUE`` (repeatable) and, with ``config_help``, ``--config FILE``."""
    if config_help:
        parser.add_argument("--config", help=config_help)
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="set one field of the configuration by its dotted name, after --config and the other "
                        "flags, e.g. --set train.optim.lr=1e-3; VALUE is read as the field's type (none, true / "
                        "false, comma-separated lists, JSON); repeatable")


def read_config(path: str, cls, variable: str = "config"):
    """``--config``'s file (JSON, or Python defining ``variable``) as a ``cls``; CommandError naming the flag."""
    from jaxanom.app.configs import ConfigError, load_config

    try:
        return load_config(path, cls, variable)
    except ConfigError as error:
        raise CommandError(f"--config {error}") from None


def with_set(config, args):
    """``config`` with the ``--set`` assignments, checked whole; CommandError naming the flag."""
    from jaxanom.app.configs import ConfigError, override

    try:
        return override(config, args.set)
    except ConfigError as error:
        raise CommandError(f"--set {error}") from None


def add_common(parser, progress: bool, overwrite: bool = True) -> None:
    """``--overwrite`` and ``--no-progress`` where a command has them."""
    if overwrite:
        parser.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty output folder")
    if progress:  # a bar drawn into a log file or a pipe is a wall of carriage returns
        parser.add_argument("--no-progress", action="store_true", default=not sys.stderr.isatty(),
                            help="no progress bar (the default where stderr is not a terminal)")


class _KeepIndented(argparse.HelpFormatter):
    """argparse's wrapping, except for lines starting with a space (the methods' listing), kept as written."""

    def _fill_text(self, text, width, indent):
        return "\n".join(line if line.startswith(" ") else super(_KeepIndented, self)._fill_text(line, width, indent)
                         for line in text.splitlines())


def add_methods(parser, unavailable: tuple[str, ...] = ()) -> None:
    """``--methods`` (the registered methods listed with their descriptions under the help, but those
    needing an input of ``unavailable``) and ``--plugin``."""
    from jaxanom.app.scoring import describe

    parser.add_argument("--methods", type=method_list, help=f"comma-separated names of the methods listed below "
                        f"(default: {DEFAULT_METHODS})")
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE",
                        help="import this Python module first, which registers its own methods (repeatable)")
    parser.formatter_class = _KeepIndented
    parser.epilog = "methods (plug-ins add theirs):\n" + describe(unavailable)


def load_plugins(args) -> None:
    """Import the ``--plugin`` modules (their methods are registered on import)."""
    from jaxanom.app.scoring import load_plugin

    for module in args.plugin:
        try:
            load_plugin(module)
        except ModuleNotFoundError as error:
            if error.name is None or not (module + ".").startswith(error.name + "."):
                raise  # the plug-in itself imports something missing: its traceback says what
            raise CommandError(f"--plugin {module}: no module named {error.name!r} on the Python path") from None


def add_scoring(parser) -> None:
    """Flags of the commands that score anomalies: statistics, methods, plug-ins, metric conventions, --out."""
    from jaxanom.metrics.anomaly import AP_CONVENTIONS

    parser.add_argument("--stats", help="SML statistics .npz (from fit-stats); needed by the sml* and cudam methods")
    add_methods(parser)
    parser.add_argument("--fpr-convention", choices=["first", "interp", "nearest", "strict"],
                        help="FPR at 95%% TPR: first (default; Fishyscapes, SMIYC), interp (ood-metrics), nearest, strict")
    parser.add_argument("--ap-convention", choices=AP_CONVENTIONS, default="step",
                        help="on the exact curve: step (scikit-learn; the SMIYC kit's rule since August 2023, "
                        "on its binned curve: evaluate --convention smiyc), trapz (np.trapz over the points: the "
                        "kit's rule before August 2023) or envelope (VOC, MMF Eq. 7)")
    parser.add_argument("--out", required=True, help="output folder")


def out_folder(path: str, overwrite: bool, *, hint: str = "pass --overwrite") -> Path:
    """An output folder that is new or empty (unless ``overwrite``), claimed for this command.

    The claim comes first and is atomic (see ``claim``), so of two commands started on one
    folder, the second fails here instead of mixing its files with the first's.
    """
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise CommandError(f"--out {folder}: exists and is not a folder")
    existed = {p.name for p in folder.iterdir() if p.is_dir()} if folder.is_dir() else None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise CommandError(f"--out {folder}: cannot create the folder ({error.strerror})") from None
    marker = folder / CLAIM
    claim(marker, f"--out {folder}")
    if not overwrite and any(p.name != CLAIM for p in folder.iterdir()):
        _claimed.remove(marker)
        marker.unlink()
        raise CommandError(f"--out {folder}: folder exists and is not empty; choose another or {hint}")
    _outputs.append((folder, existed))
    return folder


def check_out_outside(out: str, read: dict[str, str | None]) -> None:
    """CommandError when ``out`` is, or lies inside, a folder the command reads (``{flag: folder}``,
    None where not given): a command that reads a run never writes into it."""
    from jaxanom.app.predict import inside

    for flag, folder in read.items():
        if folder is not None and inside(Path(out), Path(folder)):
            raise CommandError(f"--out {out}: lies inside {flag} {folder}, which this command only reads; "
                               "choose a folder outside it")


def end_outputs(failed: bool) -> None:
    """When a command ends; if it ``failed``, remove the folders its ``out_folder`` calls created that
    stayed empty (``--out`` itself, or e.g. ``scores/`` of a ``score`` refused at its first image),
    so a retry finds them as before."""
    while _outputs:
        folder, existed = _outputs.pop()
        if not failed or not folder.is_dir():
            continue
        for child in folder.iterdir():
            if child.is_dir() and not child.is_symlink() and child.name not in (existed or ()):
                for root, _, _ in os.walk(child, topdown=False):
                    with contextlib.suppress(OSError):
                        os.rmdir(root)  # only if empty
        if existed is None:
            with contextlib.suppress(OSError):
                folder.rmdir()


def claim(marker: Path, what: str) -> None:
    """Create ``marker`` exclusively (``O_CREAT | O_EXCL``: atomic, one winner) until ``release_claims``.

    The marker holds ``<pid> <host> <start time>`` of its process. A marker left by a process that
    is gone from this host (killed by SIGKILL, a scheduler, a reboot) is taken over, with its
    unfinished temporary files, and says so in one line; one from a live process, or from another
    host, refuses.
    """
    for attempt in range(2):
        try:
            fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
            break
        except FileExistsError:
            if attempt == 0 and _take_over(marker):
                continue
            raise CommandError(f"{what}: another jaxanom command is writing there ({marker} exists: "
                               f"{_describe(marker)}); wait for it, or delete that file if none is running") from None
        except OSError as error:
            raise CommandError(f"{what}: cannot write there ({error.strerror})") from None
    with os.fdopen(fd, "w") as f:
        f.write(f"{os.getpid()} {socket.gethostname()} {_start_time(os.getpid())}\n")
    _claimed.append(marker)


def _start_time(pid: int) -> str:
    """When process ``pid`` started (clock ticks since boot, Linux), to tell a reused PID apart; "-" elsewhere."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return "-"


def _owner(text: str) -> tuple[int, str | None, str] | None:
    """``(pid, host or None, start time)`` of a marker's text; None if it is not one."""
    fields = text.split()
    if not fields or not fields[0].isdigit():
        return None
    return int(fields[0]), fields[1] if len(fields) > 1 else None, fields[2] if len(fields) > 2 else "-"


def _gone(owner: tuple[int, str | None, str]) -> bool:
    """Whether the marker's process no longer runs on this host (never for another host's)."""
    pid, host, started = owner
    if host is not None and host != socket.gethostname():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's live process
        pass
    return started != "-" and _start_time(pid) not in (started, "-")  # the PID was reused


def _describe(marker: Path) -> str:
    try:
        owner = _owner(marker.read_text())
    except OSError:
        owner = None
    return "its process is unknown" if owner is None else f"process {owner[0]} on {owner[1] or 'this host'}"


def _take_over(marker: Path) -> bool:
    """Remove a stale ``marker`` and its owner's temporaries; True if it was stale (or is gone)."""
    try:
        text = marker.read_text()
    except FileNotFoundError:
        return True
    except OSError:
        return False
    owner = _owner(text)
    if owner is None or not _gone(owner):
        return False
    aside = marker.with_name(f"{marker.name}.stale-{os.getpid()}")
    try:
        os.rename(marker, aside)  # atomic: of two commands taking over, one moves it
    except FileNotFoundError:
        return True
    if aside.read_text() != text:  # a live command claimed it between our read and the rename: give it back
        with contextlib.suppress(FileExistsError):
            os.link(aside, marker)
        aside.unlink()
        return False
    aside.unlink()
    removed = remove_temporaries(marker)
    print(f"jaxanom: took over {marker} from process {owner[0]}, which is no longer running; removed "
          f"{removed} unfinished temporary file(s)", file=sys.stderr)
    return True


def remove_temporaries(marker: Path) -> int:
    """Delete the temporaries (``.<name>.*.tmp``, see ``jaxanom.io``) of the claim ``marker``: under
    its folder (a folder's claim) or beside the file it claims. Returns how many went."""
    if marker.name == CLAIM:
        found = []
        for root, dirs, files in os.walk(marker.parent):
            found += [Path(root) / name for name in dirs + files if name.startswith(".") and name.endswith(".tmp")]
            dirs[:] = [name for name in dirs if not (name.startswith(".") and name.endswith(".tmp"))]
    else:
        target = marker.name[:-len(CLAIM)]
        found = list(marker.parent.glob(f".{glob.escape(target)}.*.tmp"))
    for path in found:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return len(found)


def release_claims() -> None:
    """Remove this process's claim markers (``main`` calls it when a command ends, however it ends)."""
    while _claimed:
        _claimed.pop().unlink(missing_ok=True)


def load_stats(path: str | None):
    """``(mean, std)`` from a statistics .npz, or None."""
    if path is None:
        return None
    from jaxanom.sml import load_stats as load

    try:
        mean, std, _ = load(path)
    except ValueError as error:
        raise CommandError(f"--stats {path}: {error}") from None
    return mean, std


class StreamedArray:
    """An array in a .npy file, or called ``name`` in a .npz file, read one image (leading index) at a time.

    Both are read sequentially, one image's bytes after the other (a .npz member is decompressed
    as it goes), so resident memory holds one image whatever the file's size: the pages of a
    memory map would count as resident once touched. An array stored in Fortran order is
    memory-mapped (.npy) or read whole (.npz). Reading errors (empty, truncated or damaged
    files) become a one-line CommandError.
    """

    def __init__(self, path: str, name: str):
        import numpy as np

        self.path, self.name = Path(path), name
        if not self.path.is_file():
            raise CommandError(f"--{name} {path}: no such file")
        self._whole = None
        with self._reading():
            with open(self.path, "rb") as f:
                self._member = f"{name}.npy" if f.read(4) == b"PK\x03\x04" else None  # np.load's test for .npz
            if self._member is not None:
                with zipfile.ZipFile(self.path) as archive:
                    found = [m[:-4] for m in archive.namelist() if m.endswith(".npy")]
                    if name not in found:
                        raise CommandError(f"--{name} {path}: expected an array named {name!r}, found {found}")
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
        return _converted_errors(f"--{self.name} {self.path}: not a readable .npy/.npz file")


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
def _converted_errors(prefix: str):
    """Reading errors inside the block become a one-line CommandError starting with ``prefix``."""
    try:
        yield
    except _UNREADABLE as error:
        raise CommandError(f"{prefix} ({type(error).__name__}: {error})") from None
