"""Config files, one format for every command: the JSON of ``jaxanom.config_codec``, or Python.

``load_config(path, cls, variable)`` reads

- a JSON file: ``config_codec.encode``'s object of a ``cls`` (any part of it: the fields left out
  keep their defaults), or an object whose ``"config"`` member is one (a demo's ``results.json``);
  a run's ``experiment.json`` is such a file, so ``train --config RUN/experiment.json`` repeats a run;
- a Python file (config-as-code): run, it defines ``variable`` (a ``cls``).

Either way no number field holds NaN or infinity (``config_codec``: none of them takes one).

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

__all__ = ["ConfigError", "encode", "load_config", "override"]

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
