"""The flags several commands share, and the argparse types of their values."""
from __future__ import annotations

import argparse
import sys

from jaxanom.app.commands.inputs import DEFAULT_METHODS
from jaxanom.errors import InputError


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


def size_hw(text: str | None) -> tuple[int, int] | None:
    """``(H, W)`` from ``--size HxW`` (e.g. ``512x1024``), or None for None."""
    if text is None:
        return None
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise InputError("size", f": expected HEIGHTxWIDTH with positive integers (e.g. 512x1024), got {text!r}")
    return int(parts[0]), int(parts[1])


VALUES = "VALUE is read as the field's or option's type (none, true / false, comma-separated lists, JSON); repeatable"
METHOD_OPTIONS = ("methods.METHOD.OPTION=VALUE sets an option of a method (listed below with its type and default), "
                  "e.g. --set methods.cudam.cudam_sigma=2e4")


def add_config(parser, example: str | None = None, config_help: str | None = None, set_help: str | None = None) -> None:
    """``--set NAME=VALUE`` (repeatable; the app function's ``overrides``; ``set_help``: what it sets
    for this command, default the configuration's fields by dotted name, with ``--set example``)
    and, with ``config_help``, ``--config FILE``. Help texts write examples as whole flags in
    backticks, which a test runs."""
    if config_help:
        parser.add_argument("--config", help=config_help)
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help=(set_help or "set one field of the configuration by its dotted name, after --config and "
                              f"the other flags, e.g. `--set {example}`") + f"; {VALUES}")


def add_plugin(parser) -> None:
    """``--plugin MODULE`` (repeatable; the app function's ``plugins``)."""
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE",
                        help="import this Python module (a dotted name on the Python path) first, which registers its "
                        "own methods, objectives or other entries (repeatable); a run records the plug-ins its "
                        "experiment uses and imports them whenever it is read")


def add_common(parser, progress: bool, overwrite: bool = True) -> None:
    """``--overwrite`` where a command has it, and ``--no-progress`` (which does nothing where a
    command draws no ``progress`` bar)."""
    if overwrite:
        parser.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty output folder")
    if progress:  # a bar drawn into a log file or a pipe is a wall of carriage returns
        parser.add_argument("--no-progress", action="store_true", default=not sys.stderr.isatty(),
                            help="no progress bar (the default where stderr is not a terminal)")
    else:  # every command takes it, so one script line can pass it to any
        parser.add_argument("--no-progress", action="store_true", help="accepted for uniformity: this command draws "
                            "no progress bar")


class _KeepIndented(argparse.HelpFormatter):
    """argparse's wrapping, except for lines starting with a space (the methods' listing), kept as written."""

    def _fill_text(self, text, width, indent):
        return "\n".join(line if line.startswith(" ") else super(_KeepIndented, self)._fill_text(line, width, indent)
                         for line in text.splitlines())


def add_methods(parser, unavailable: tuple[str, ...] = ()) -> None:
    """``--methods`` (the registered methods listed with their descriptions under the help, but those
    needing an input of ``unavailable``) and ``--plugin``. The listing is made when the help is
    shown: building the parsers loads no method, so a broken installed plug-in breaks no other
    command's help or run."""
    from jaxanom.app.scoring import describe

    parser.add_argument("--methods", type=method_list, help=f"comma-separated names of the methods listed below "
                        f"(default: {','.join(DEFAULT_METHODS)})")
    add_plugin(parser)
    parser.formatter_class = _KeepIndented
    format_help = parser.format_help

    def with_methods() -> str:
        parser.epilog = "methods (plug-ins add theirs):\n" + describe(unavailable)
        return format_help()

    parser.format_help = with_methods


def add_protocol(parser, help: str) -> None:
    """``--protocol NAME`` (the app function's ``protocol``, default native): any registered protocol,
    a plug-in's included, looked up when the command runs; its help is ``help`` (what the protocol
    does for this command) followed by jaxanom's own protocols."""
    from jaxanom.app.commands.inputs import own_entries

    parser.add_argument("--protocol", default="native", metavar="NAME",
                        help=f"{help}: " + own_entries("protocols").replace("%", "%%") + "; or a plug-in's (--plugin "
                        "MODULE, or the jaxanom.protocols entry points) (default: %(default)s)")


def add_evaluators(parser, need: str = "") -> None:
    """``--evaluators NAMES`` (the app function's ``evaluators``): registered evaluators of a
    method's scores, a plug-in's included, looked up when the command runs; ``need``: what they
    need besides (e.g. " (with --labels)"), then jaxanom's own evaluators."""
    from jaxanom.app.commands.inputs import own_entries

    parser.add_argument("--evaluators", metavar="NAMES",
                        help=f"comma-separated evaluators also fed each method's scores{need}, their metrics in "
                        "metrics.json under the method's \"evaluators\": " + own_entries("evaluators").replace("%", "%%")
                        + "; or a plug-in's (--plugin MODULE, or the jaxanom.evaluators entry points)")


def add_scoring(parser) -> None:
    """Flags of the commands that score anomalies: statistics, methods, plug-ins, metric conventions, --out."""
    from jaxanom.app.commands.score import AP_CONVENTIONS

    parser.add_argument("--stats", help="SML statistics .npz (from fit-stats); needed by the sml* and cudam methods")
    add_methods(parser)
    parser.add_argument("--fpr-convention", choices=["first", "interp", "nearest", "strict"],
                        help="FPR at 95%% TPR: first (default; Fishyscapes, SMIYC), interp (ood-metrics), nearest, strict")
    parser.add_argument("--ap-convention", choices=AP_CONVENTIONS, default="step",
                        help="on the exact curve: step (scikit-learn; the SMIYC kit's rule since August 2023, "
                        "on its binned curve: evaluate --convention smiyc), trapz (np.trapz over the points: the "
                        "kit's rule before August 2023) or envelope (VOC, MMF Eq. 7)")
    parser.add_argument("--out", required=True, help="output folder")
