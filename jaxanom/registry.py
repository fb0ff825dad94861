"""Named plug-ins of one kind (scoring methods, training objectives, ...): one registry type for all.

A ``Registry`` maps names to entries (a ``method_registry.Method``, an ``objectives.Objective``
class, ...). Where its entries come from, loaded once, on first use (``load``):

- jaxanom's own: the modules its ``builtins()`` names, imported first, so no plug-in can take one
  of their names;
- installed packages: the modules (or objects) of the entry-point group ``jaxanom.<kinds>``
  (``jaxanom.methods``, ``jaxanom.objectives``), unless the environment variable
  ``JAXANOM_DISABLE_ENTRY_POINTS`` is set (to anything but ``""`` or ``0``); one that fails to
  load is left out and named only when a name it might have provided is asked for
  (``broken_note``), so it breaks nothing that does not need it;
- any module imported by the caller (``load_plugin``, the commands' ``--plugin MODULE``).

Each of those modules registers its entries when imported. A name follows ``NAME_RULE`` (it may
become a file or folder name of a command's outputs); a name already taken by another entry is
refused in one line naming the module that has it. ``origin(name)`` is the module that registered
a name, and ``plugin_module(name)`` that module when it is not jaxanom's own: what a run records
so that every later reading of it imports it again.
"""
from __future__ import annotations

import importlib
import os
import re
from typing import Callable, Generic, Iterable, TypeVar

DISABLE_ENTRY_POINTS = "JAXANOM_DISABLE_ENTRY_POINTS"  # environment variable: installed plug-ins not loaded

# letters, digits, ``_``, ``-`` and ``.``, never ``.`` or ``..``: never a path
NAME = re.compile(r"[A-Za-z0-9_.-]+")
NAME_RULE = "letters, digits, '_', '-', '.' (not '.' or '..')"

T = TypeVar("T")
_ALL: list["Registry"] = []  # every registry made, loaded before a plug-in is imported


def is_name(text) -> bool:
    """Whether ``text`` may name a registered entry (``NAME_RULE``): a plain name, never a path."""
    return isinstance(text, str) and NAME.fullmatch(text) is not None and text not in (".", "..")


def is_module_name(text) -> bool:
    """Whether ``text`` is a module's dotted name (``my_scores``, ``package.module``)."""
    return isinstance(text, str) and bool(text) and all(part.isidentifier() for part in text.split("."))


def entry_points_disabled() -> bool:
    """Whether ``JAXANOM_DISABLE_ENTRY_POINTS`` switches the installed plug-ins off."""
    return os.environ.get(DISABLE_ENTRY_POINTS, "") not in ("", "0")


class Registry(Generic[T]):
    """The entries of one kind by name. ``kind``: the word for one entry in messages ("method");
    ``group``: its entry-point group; ``builtins()``: the dotted names of jaxanom's own modules
    registering entries; ``describe(entry, origin)``: the entry in a conflict message (default:
    its module)."""

    def __init__(self, kind: str, group: str, builtins: Callable[[], Iterable[str]],
                 describe: Callable[[T, str], str] | None = None):
        self.kind, self.group, self._builtins = kind, group, builtins
        self._describe = describe or (lambda entry, origin: origin)
        self.entries: dict[str, T] = {}
        self.origins: dict[str, str] = {}  # name -> the module that registered it
        self.broken: list[str] = []  # one line per entry point that failed to load
        self.loaded = False
        _ALL.append(self)

    def add(self, name: str, entry: T, origin: str) -> T:
        """Register ``entry`` as ``name`` by the module ``origin``; ValueError in one line when ``name``
        is not a name (``NAME_RULE``) or another entry has it (the same entry again, its module
        imported twice, keeps its origin). Returns the registered entry."""
        if not is_name(name):
            raise ValueError(f"{self.kind} name: expected {NAME_RULE}, got {name!r}")
        if name in self.entries and self.entries[name] != entry:
            raise ValueError(f"{self.kind} {name!r}: already registered by "
                             f"{self._describe(self.entries[name], self.origins[name])}; {origin} cannot register "
                             "another under the same name")
        if name not in self.entries:
            self.entries[name], self.origins[name] = entry, origin
        return self.entries[name]

    def find(self, name: str) -> T | None:
        """The entry called ``name``, or None (after ``load``)."""
        self.load()
        return self.entries.get(name)

    def names(self) -> tuple[str, ...]:
        """Every registered name: jaxanom's own first, in the order of ``builtins()`` whichever module
        was imported first, then installed plug-ins', then loaded modules'."""
        self.load()
        own = {module: index for index, module in enumerate(self._builtins())}
        return tuple(sorted(self.entries, key=lambda name: own.get(self.origins[name], len(own))))

    def origin(self, name: str) -> str:
        """The module that registered ``name``."""
        return self.origins[name]

    def plugin_module(self, name: str) -> str | None:
        """The module that registered ``name`` when it is not jaxanom's own; None for jaxanom's."""
        origin = self.origins[name]
        return None if origin == "jaxanom" or origin.startswith("jaxanom.") else origin

    def load(self) -> None:
        """Register jaxanom's own entries, then the installed plug-ins' (once)."""
        if self.loaded:
            return
        for module in self._builtins():
            importlib.import_module(module)
        from importlib.metadata import entry_points

        self.broken.clear()
        for entry in () if entry_points_disabled() else entry_points(group=self.group):
            try:
                entry.load()
            except Exception as error:  # noqa: BLE001  a broken installed plug-in: named when its names are needed
                reason = str(error).strip().splitlines()[0] if str(error).strip() else ""
                self.broken.append(f"the {self.group} entry point {entry.name} = {entry.value} "
                                   f"({entry.dist.name if entry.dist else 'unknown distribution'}) failed to load "
                                   f"({type(error).__name__}: {reason})")
        self.loaded = True

    def broken_note(self) -> str:
        """For an error about unknown names: the entry points that failed to load (which might have
        provided them), or ""."""
        if not self.broken:
            return ""
        return f"; {'; '.join(self.broken)} (fix or uninstall it, or set {DISABLE_ENTRY_POINTS}=1)"


class PluginError(ValueError):
    """A plug-in module that could not be imported: ``module`` and, in one line, ``reason``."""

    def __init__(self, module: str, reason: str):
        self.module, self.reason = module, reason
        super().__init__(f"{module}: {reason}")


def load_plugin(module: str) -> None:
    """Import ``module`` (a dotted name on ``sys.path``), which registers its entries of any kind;
    every registry made so far loads jaxanom's own entries first, so a plug-in cannot take one of
    their names. ``PluginError`` in one line when it is not found, or when its import raises (a name
    already taken, a missing dependency, any bug: the error and the plug-in's own file and line)."""
    import traceback
    from pathlib import Path

    for registry in _ALL:
        registry.load()
    try:
        importlib.import_module(module)
    except ModuleNotFoundError as error:
        if error.name is None or not (module + ".").startswith(error.name + "."):
            raise PluginError(module, f"importing it failed: {error}") from None
        raise PluginError(module, f"no module named {error.name!r} on the Python path") from None
    except Exception as error:  # noqa: BLE001  a plug-in's own failure: one line naming it and where
        frames = traceback.extract_tb(error.__traceback__)
        package = str(Path(__file__).parent)  # the plug-in's own line, not jaxanom's nor importlib's
        frame = next((f for f in reversed(frames) if not f.filename.startswith((package, "<"))), frames[-1])
        raise PluginError(module, f"importing it raised {type(error).__name__}: "
                          f"{str(error).splitlines()[0] if str(error) else ''} ({frame.filename}, line "
                          f"{frame.lineno})") from None
