"""What every command shares: the error type, output folders, flags and array loading."""
from __future__ import annotations

from pathlib import Path


class CommandError(Exception):
    """Bad input to a command: printed as one line, exit status 2."""


def add_common(parser, progress: bool, overwrite: bool = True) -> None:
    """``--overwrite`` and ``--no-progress`` where a command has them."""
    if overwrite:
        parser.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty output folder")
    if progress:
        parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_scoring(parser) -> None:
    """Flags of the commands that score anomalies: statistics, methods, metric conventions, --out."""
    from jaxanom.methods import METHODS
    from jaxanom.metrics.anomaly import AP_CONVENTIONS

    parser.add_argument("--stats", help="SML statistics .npz (from fit-stats); needed by the sml* and cudam methods")
    parser.add_argument("--methods", default="msp,max_logit,entropy,energy,sml,sml_post",
                        help=f"comma-separated, from {', '.join(METHODS)} (default: %(default)s)")
    parser.add_argument("--fpr-convention", choices=["first", "interp", "nearest", "strict"], default="first")
    parser.add_argument("--ap-convention", choices=AP_CONVENTIONS, default="step",
                        help="step (scikit-learn), trapz (SMIYC before 2023) or envelope (VOC, MMF Eq. 7)")
    parser.add_argument("--out", required=True, help="output folder")


def out_folder(path: str, overwrite: bool) -> Path:
    """An output folder that is new or empty, unless ``overwrite``."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise CommandError(f"--out {folder}: exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()) and not overwrite:
        raise CommandError(f"--out {folder}: folder exists and is not empty; choose another or pass --overwrite")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def load_stats(path: str | None):
    """``(mean, std)`` from a statistics .npz, or None."""
    if path is None:
        return None
    from jaxanom.sml import load_stats as load

    mean, std, _ = load(path)
    return mean, std


def load_array(path: str, name: str):
    """The array in a .npy file, or the array called ``name`` in a .npz file."""
    import numpy as np

    file = Path(path)
    if not file.is_file():
        raise CommandError(f"--{name} {path}: no such file")
    try:
        loaded = np.load(file, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise CommandError(f"--{name} {path}: not a readable .npy/.npz file ({error})") from None
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            if name not in loaded.files:
                raise CommandError(f"--{name} {path}: expected an array named {name!r}, found {loaded.files}")
            return loaded[name]
    return loaded
