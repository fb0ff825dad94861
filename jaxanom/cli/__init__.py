"""The ``jaxanom`` command: demo, train, fit-stats, evaluate, predict, score, convert-weights.

Every command writes into an output folder that must be new or empty (``--overwrite`` allows
a non-empty one), and ends with a non-zero exit and a one-line reason on bad input.
One module per command; each has ``add_parser(commands)`` and ``run(args)``, which calls the
command's one function in ``jaxanom.app.commands``. Bad input (``jaxanom.errors.InputError``, a
missing or existing file, a file system refusal) is one line naming the flag, exit status 2; any
other error is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading

from jaxanom.app.outputs import end_outputs, release_claims
from jaxanom.cli import convert_weights, demo, evaluate, fit_stats, predict, score, train
from jaxanom.errors import InputError

COMMANDS = (demo, train, fit_stats, evaluate, predict, score, convert_weights)


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "handler"):
        parser.print_help()
        return 2
    failed = True
    try:
        with _sigterm_as_interrupt():
            args.handler(args)
        failed = False
    except InputError as error:
        print(f"jaxanom {args.command}: error: {error.render(args.spell)}", file=sys.stderr)
        return 2
    except (FileNotFoundError, FileExistsError) as error:
        print(f"jaxanom {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # the file system refused (permissions, full disk, read-only): one line too
        print(f"jaxanom {args.command}: error: {error.strerror or error}: {error.filename or ''}", file=sys.stderr)
        return 2
    except Terminated:
        print(f"jaxanom {args.command}: terminated (SIGTERM); nothing half-written is left", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print(f"jaxanom {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        release_claims()
        end_outputs(failed)
    return 0


class Terminated(KeyboardInterrupt):
    """SIGTERM (schedulers, containers, ``kill``), raised where SIGINT raises KeyboardInterrupt."""


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """Within the block, SIGTERM unwinds the command as Ctrl-C does: temporaries and claims go."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxanom", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(commands)
    for subparser in commands.choices.values():
        subparser.set_defaults(spell=_speller(subparser))
    return parser


def _speller(parser: argparse.ArgumentParser):
    """``spell(argument)``: the flag (``--stats``) or positional (``IN``) of ``parser`` that sets the
    app function's ``argument``, found through its destination (``ALIASES`` of the command's module
    for names that differ, e.g. ``plugins`` -> ``plugin``); other names are kept as they are."""
    flags = {}
    for action in parser._actions:
        long = [option for option in action.option_strings if option.startswith("--")]
        flags[action.dest] = long[0] if long else action.option_strings[0] if action.option_strings else (
            action.metavar or action.dest)
    aliases = parser.get_default("aliases") or {}

    def spell(argument: str) -> str:
        return flags.get(aliases.get(argument, argument), argument)

    return spell


if __name__ == "__main__":
    sys.exit(main())
