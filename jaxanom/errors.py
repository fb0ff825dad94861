"""The error of bad input: it names the offending argument, so each caller can say it in its own words.

A Python caller reads ``argument`` as the function's parameter name; the command line reads it as
its flag (``stats`` -> ``--stats``). Any other argument the advice mentions is written ``{name}`` in
the message and listed in ``mentions``, so it is spelled the same way. Subclassing ``ValueError``
keeps ``except ValueError`` and ``pytest.raises(ValueError)`` of callers valid. ``first_line``
shortens another library's error to fit a one-line message.
"""
from __future__ import annotations

import contextlib
from typing import Callable, Iterator


class InputError(ValueError):
    """Bad input named by ``argument`` (a parameter name); ``message`` follows that name.

    ``InputError("out", f"{folder}: exists and is not a folder")`` reads ``out /x: exists ...``
    to Python and ``--out /x: exists ...`` on the command line; a message starting with ``:``,
    ``,``, ``;`` or a space is attached without another (``InputError("track", ": needs ...")``), and one
    that writes ``{argument}`` itself (and starts with none of those) places the name there instead of in front.
    """

    def __init__(self, argument: str, message: str, *, mentions: tuple[str, ...] = ()):
        self.argument, self.message, self.mentions = argument, message, tuple(mentions)
        super().__init__(self.render())

    def render(self, spell: Callable[[str], str] = str) -> str:
        """The message with each argument's name written as ``spell(name)`` (a flag, for the command line)."""
        text = self.message
        for name in self.mentions:
            text = text.replace("{" + name + "}", spell(name))
        placeholder = "{" + self.argument + "}"
        text = text.replace(placeholder, spell(self.argument))
        if text[:1] in (":", ",", ";", " "):  # written to follow the name, even where it names it again
            return f"{spell(self.argument)}{text}"
        if placeholder in self.message:  # the message places the argument's name itself
            return text
        return f"{spell(self.argument)} {text}"


@contextlib.contextmanager
def reading(argument: str, value=None) -> Iterator[None]:
    """A plain ValueError inside the block (a reader refusing ``value``, given as ``argument``)
    becomes an InputError ``argument value: <its message>`` (``argument: <its message>`` without
    ``value``; a message that starts with ``value:`` or ``argument:`` is not prefixed with it
    twice); an InputError passes unchanged."""
    try:
        yield
    except InputError:
        raise
    except ValueError as error:
        text = str(error)
        if value is None and text.startswith(f"{argument}:"):  # the reader named the argument already
            text = text[len(argument) + 1:].lstrip()
        if value is not None and text.startswith(f"{value}:"):  # ... or the value
            text = text[len(str(value)) + 1:].lstrip()
        raise InputError(argument, f"{'' if value is None else value}: {text}") from None


def first_line(error: Exception, limit: int = 300) -> str:
    """The first line of an error's message, at most ``limit`` characters (TensorStore's run to 60 lines)."""
    lines = str(error).strip().splitlines() or [""]
    return lines[0][:limit] + (" ..." if len(lines) > 1 or len(lines[0]) > limit else "")
