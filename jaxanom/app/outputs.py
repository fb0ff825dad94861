"""Output folders and files of a command: new or empty, claimed while it writes, tidied when it fails.

A claim is a marker file created atomically, so two commands never write into one folder; one
left by a killed process is taken over with its unfinished temporaries. ``release_claims`` and
``end_outputs`` run when a command ends, however it ends.
"""
from __future__ import annotations

import contextlib
import glob
import os
import shutil
import socket
import sys
from pathlib import Path

from jaxanom.errors import InputError

CLAIM = ".jaxanom-claim"  # marker of a command writing into a folder (or beside a file), removed at its end
_claimed: list[Path] = []
_outputs: list[tuple[Path, set[str] | None]] = []  # (out folder, its subfolders when claimed, None if new)


def out_folder(path: str | Path, overwrite: bool, *, hint: str = "pass {overwrite}") -> Path:
    """An output folder that is new or empty (unless ``overwrite``), claimed for this command.

    The claim comes first and is atomic (see ``claim``), so of two commands started on one
    folder, the second fails here instead of mixing its files with the first's. ``hint`` (the
    advice when the folder is not empty) may mention ``{overwrite}`` and ``{resume}``.
    """
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise InputError("out", f"{folder}: exists and is not a folder")
    existed = {p.name for p in folder.iterdir() if p.is_dir()} if folder.is_dir() else None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError("out", f"{folder}: cannot create the folder ({error.strerror})") from None
    marker = folder / CLAIM
    claim(marker, folder)
    if not overwrite and any(p.name != CLAIM for p in folder.iterdir()):
        _claimed.remove(marker)
        marker.unlink()
        raise InputError("out", f"{folder}: folder exists and is not empty; choose another or {hint}",
                         mentions=("overwrite", "resume"))
    _outputs.append((folder, existed))
    return folder


def check_out_outside(out: str | Path, read: dict[str, str | Path | None]) -> None:
    """InputError when ``out`` is, or lies inside, a folder the command reads (``{argument: folder}``,
    None where not given): a command that reads a run never writes into it."""
    for argument, folder in read.items():
        if folder is not None and inside(Path(out), Path(folder)):
            raise InputError("out", f"{out}: lies inside {{{argument}}} {folder}, which this command only reads; "
                             "choose a folder outside it", mentions=(argument,))


def inside(path: Path, folder: Path) -> bool:
    """True when ``path`` is ``folder`` or lies under it (both resolved)."""
    path, folder = Path(path).resolve(), Path(folder).resolve()
    return path == folder or folder in path.parents


def within(out: str | Path, path: str | Path) -> Path:
    """``path``, once proven to lie inside the output folder ``out``: its folder, symlinks resolved,
    is ``out`` or under it, and its last part is a plain file name (a link there is replaced, not
    followed, by the atomic writes of ``jaxanom.io`` and by ``unlink``). InputError naming ``out``
    otherwise: a command writes and deletes inside its ``--out`` only."""
    path = Path(path)
    if path.name in ("", ".", "..") or not inside(path.parent, Path(out)):
        raise InputError("out", f"{out}: refusing to write or remove {path}, which lies outside it")
    return path


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


def claim(marker: Path, out: str | Path) -> None:
    """Create ``marker`` exclusively (``O_CREAT | O_EXCL``: atomic, one winner) until ``release_claims``;
    ``out`` is the output (folder or file) it claims, named in errors.

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
            raise InputError("out", f"{out}: another jaxanom command is writing there ({marker} exists: "
                             f"{_describe(marker)}); wait for it, or delete that file if none is running") from None
        except OSError as error:
            raise InputError("out", f"{out}: cannot write there ({error.strerror})") from None
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
