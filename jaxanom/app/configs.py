"""Config files, one format for every command: the JSON of ``jaxanom.config_codec``, or Python.

``load_config(path, cls, variable)`` reads

- a JSON file: ``config_codec.encode``'s object of a ``cls`` (any part of it: the fields left out
  keep their defaults), or an object whose ``"config"`` member is one (a demo's ``results.json``);
  a run's ``experiment.json`` is such a file, so ``train --config RUN/experiment.json`` repeats a run;
- a Python file (config-as-code): run, it defines ``variable`` (a ``cls``).

Either way no number field holds NaN or infinity (``config_codec``: none of them takes one).
A JSON config of a class with a ``plugins`` field (``Experiment``) first imports the modules it
lists, which register the names it uses (a plug-in's objective), or names the one missing.

``override(config, ["train.optim.lr=1e-3", ...])`` (``--set``) is ``config_codec.override``.
"""
from __future__ import annotations

import dataclasses
import json
import os
import runpy
from pathlib import Path
from typing import TypeVar

from jaxanom.config_codec import ConfigError, check_finite, decode, encode, override

__all__ = ["ConfigError", "encode", "import_plugins", "load_config", "load_plugin", "override"]

T = TypeVar("T")


def load_config(path: str | os.PathLike, cls: type[T], variable: str = "config", *,
                written: tuple[str, ...] = ()) -> T:
    """The ``cls`` that the JSON or Python file ``path`` holds (see the module docstring); ConfigError
    naming the file, and the field's dotted path, when it holds none. ``written``: dotted names a JSON
    file must hold, where it must be one jaxanom wrote whole (a run's experiment.json), not a user's
    partial config."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError("", "no such file", os.fspath(path))
    if path.suffix == ".py":
        return _run_python(path, cls, variable)
    try:
        values = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise ConfigError("", f"not valid JSON ({error})", os.fspath(path)) from None
    if isinstance(values, dict) and isinstance(values.get("config"), dict) and "config" not in _field_names(cls):
        values = values["config"]  # a demo's results.json: its configuration
    if isinstance(values, dict) and "plugins" in _field_names(cls):
        import_plugins(values.get("plugins"), os.fspath(path))
    for name in written:
        holder = values
        for key in name.split("."):
            if not isinstance(holder, dict) or key not in holder:
                raise ConfigError(name, "missing, in a file that jaxanom writes whole", os.fspath(path))
            holder = holder[key]
    try:
        return decode(cls, values)
    except ConfigError as error:
        raise ConfigError(error.path, error.message, os.fspath(path)) from None


def load_plugin(module: str) -> None:
    """Import the plug-in ``module`` once every kind's registry has loaded jaxanom's own names (the
    methods' and objectives' registries import ``jaxanom.builtins``' modules, which make the other
    kinds' registries: attention modules, evaluators, protocols); ``jaxanom.registry.PluginError``
    in one line when it cannot be imported."""
    from jaxanom import registry
    from jaxanom.method_registry import METHODS
    from jaxanom.objectives import OBJECTIVES

    for kind in (METHODS, OBJECTIVES):
        kind.load()
    registry.load_plugin(module)


def import_plugins(modules, source: str) -> None:
    """Import the plug-in ``modules`` a JSON config lists (not a list of names: left to ``decode``);
    ConfigError naming ``plugins``, the file and the module to install when one cannot be imported."""
    from jaxanom.registry import PluginError, is_module_name

    if not isinstance(modules, list) or not all(is_module_name(module) for module in modules):
        return
    for module in modules:
        try:
            load_plugin(module)
        except PluginError as error:
            raise ConfigError("plugins", f"the plug-in module {module!r} that registers what this config names could "
                              f"not be imported ({error.reason}); install it or put it on PYTHONPATH", source) from None


def _field_names(cls) -> set[str]:
    return {field.name for field in dataclasses.fields(cls)}


def _run_python(path: Path, cls: type[T], variable: str) -> T:
    try:
        value = runpy.run_path(os.fspath(path)).get(variable)
    except SystemExit as stop:
        raise ConfigError("", f"called sys.exit({stop.code!r}) instead of defining `{variable}`",
                          os.fspath(path)) from None
    except Exception as error:  # the config is the user's Python: any failure is a bad config, in one line
        where = f" (line {error.lineno})" if isinstance(error, SyntaxError) else ""
        raise ConfigError("", f"{type(error).__name__}{where}: {error}", os.fspath(path)) from None
    if not isinstance(value, cls):
        raise ConfigError("", f"expected it to define `{variable} = {cls.__name__}(...)`, found "
                          f"{type(value).__name__}", os.fspath(path))
    try:  # what a JSON config's decoding refuses: NaN or infinity in a number field
        check_finite(encode(value))
    except ConfigError as error:
        raise ConfigError(error.path, error.message, os.fspath(path)) from None
    return value
