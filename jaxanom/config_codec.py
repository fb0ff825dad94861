"""One JSON form for every frozen config dataclass, and ``NAME=VALUE`` overrides parsed by the field types.

``encode(config)`` gives plain JSON values in ``dataclasses.asdict``'s layout: a dataclass is an
object of all its fields, a tuple a list, an Enum its value. ``decode(cls, values)`` is its strict
inverse, driven by the declared field types (``int``, ``float``, ``bool``, ``str``, ``Literal``,
Enums, nested dataclasses, ``tuple[X, ...]`` and fixed tuples, ``X | None``, unions): an unknown
key, a value of the wrong type (NaN and infinity are no ``float``'s: no config field takes them) or a
missing field without a default raises ``ConfigError`` naming
the dotted path (``train.optim.lr``), what was expected and what came, and the dataclasses' own
checks run as they are built. A field left out keeps its default; the default of a nested config
is the enclosing config's (``{"experiment": {"train_frames": 8}}`` changes one field of a demo's
own experiment).

A field typed with a family of registered configs (a class with a ``class_named(name)``
classmethod, such as ``objectives.Objective``) is stored with the registered ``name`` of its
class, which picks the class when it is read back.

A field declared with ``metadata={OMITTED_AT_DEFAULT: True}`` is left out of ``encode``'s object
while it holds its default (read back as the default): a field added later (``Experiment.plugins``)
changes neither the JSON of the configs that do not use it nor anything named after that JSON.

``override(config, ["train.optim.lr=1e-3", ...])`` applies ``--set`` assignments: each VALUE is
read as the field's type (``none`` for None, ``true`` / ``false``, comma-separated lists or JSON
for tuples, a registered name or a JSON object for a nested config, a number after a dot indexes a
tuple), then the whole config is decoded again, so it is checked at once before any work.
"""
from __future__ import annotations

import dataclasses
import enum
import json
import math
import types
import typing
from typing import Any, Sequence

import numpy as np

_MISSING = dataclasses.MISSING
OMITTED_AT_DEFAULT = "omitted_at_default"  # field metadata: left out of encode's object while at its default
_NONE_WORDS = ("none", "null")
_BOOLS = {"true": True, "yes": True, "on": True, "1": True, "false": False, "no": False, "off": False, "0": False}


class ConfigError(ValueError):
    """A configuration value that does not fit: ``path`` is its dotted name ("" for the whole config),
    ``source`` the file it came from ("" if none)."""

    def __init__(self, path: str, message: str, source: str = ""):
        text = f"{path}: {message}" if path else message
        super().__init__(f"{source}: {text}" if source else text)
        self.path, self.message, self.source = path, message, source


def encode(value: Any) -> Any:
    """``value`` (a dataclass, tuple, Enum or scalar) as plain JSON values (``dataclasses.asdict``'s layout)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not (f.metadata.get(OMITTED_AT_DEFAULT) and getattr(value, f.name) == _field_default(f))}
    if isinstance(value, (tuple, list)):
        return [encode(item) for item in value]
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, np.generic):  # e.g. a float64 computed with NumPy
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"encode: a {type(value).__name__} has no JSON form in a config")


def decode(kind: Any, values: Any, path: str = "", base: Any = _MISSING) -> Any:
    """The value of type ``kind`` that ``values`` (JSON) encodes; ConfigError naming ``path`` otherwise.

    ``base``: the value the fields left out of a dataclass's object are taken from (default: the
    dataclass's field defaults)."""
    origin = typing.get_origin(kind)
    if len(_options(kind)) > 1:
        return _decode_union(kind, values, path, base)
    if origin is typing.Literal:
        if not any(values == choice and type(values) is type(choice) for choice in typing.get_args(kind)):
            raise ConfigError(path, f"expected {describe(kind)}, got {values!r}")
        return values
    if origin is tuple or kind is tuple:
        return _decode_tuple(kind, values, path)
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        try:
            return kind(values)
        except ValueError:
            raise ConfigError(path, f"expected {describe(kind)}, got {values!r}") from None
    if dataclasses.is_dataclass(kind):
        return _decode_dataclass(kind, values, path, base)
    if kind in (bool, int, float, str):
        fits = (isinstance(values, bool) if kind is bool else isinstance(values, str) if kind is str
                else isinstance(values, (int, float) if kind is float else int) and not isinstance(values, bool))
        if not fits:
            raise ConfigError(path, f"expected {describe(kind)}, got {values!r}")
        if kind is float and not math.isfinite(values):  # no config field takes NaN or infinity
            raise ConfigError(path, f"expected a finite number, got {values!r}")
        return float(values) if kind is float else values
    if kind is Any:
        return values
    raise TypeError(f"decode: {path or 'config'} has the type {kind!r}, which has no JSON form")


def describe(kind: Any) -> str:
    """``kind`` in words, for error messages."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if len(_options(kind)) > 1:
        return " or ".join("none" if arg is type(None) else describe(arg) for arg in args)
    if origin is typing.Literal:
        return f"one of {args}"
    if origin is tuple or kind is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_plural(args[0])}"
        return f"a list of {len(args)} values ({', '.join(describe(arg) for arg in args)})" if args else "a list"
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return f"one of {tuple(member.value for member in kind)}"
    if isinstance(kind, type) and hasattr(kind, "class_named"):
        return f"a {kind.__name__}: an object with a registered 'name'"
    if dataclasses.is_dataclass(kind):
        return f"an object of {kind.__name__} fields"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(kind, repr(kind))


def _plural(kind: Any) -> str:
    return {bool: "true / false values", int: "integers", float: "numbers", str: "strings"}.get(kind, describe(kind))


def _decode_union(kind, values, path, base):
    options = _options(kind)
    if values is None and type(None) in options:
        return None
    others = [option for option in options if option is not type(None)]
    if len(others) == 1:
        return decode(others[0], values, path, _MISSING if base is None else base)
    for option in others:
        try:
            return decode(option, values, path)
        except ConfigError:
            continue
    raise ConfigError(path, f"expected {describe(kind)}, got {values!r}")


def _decode_tuple(kind, values, path):
    if not isinstance(values, (list, tuple)):
        raise ConfigError(path, f"expected {describe(kind)}, got {values!r}")
    args = typing.get_args(kind)
    if not args:
        kinds = [Any] * len(values)
    elif len(args) == 2 and args[1] is Ellipsis:
        kinds = [args[0]] * len(values)
    elif len(args) != len(values):
        raise ConfigError(path, f"expected {describe(kind)}, got {len(values)}: {values!r}")
    else:
        kinds = args
    return tuple(decode(item_kind, item, _join(path, str(index))) for index, (item_kind, item)
                 in enumerate(zip(kinds, values)))


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _config_class(kind: type, values: dict, path: str, base: Any) -> type:
    """The dataclass ``values`` holds: ``kind``, or in a registered family the class its ``name`` names."""
    if not hasattr(kind, "class_named"):
        return kind
    if "name" in values:
        if not isinstance(values["name"], str):
            raise ConfigError(_join(path, "name"), f"expected a registered name, got {values['name']!r}")
        try:
            cls = kind.class_named(values["name"])
        except ValueError as error:
            raise ConfigError(_join(path, "name"), str(error)) from None
    elif base is not _MISSING and isinstance(base, kind):
        cls = type(base)
    else:
        raise ConfigError(_join(path, "name"), f"missing: a {kind.__name__} is read by its registered name")
    if not issubclass(cls, kind):
        raise ConfigError(path, f"expected a {kind.__name__}, got {values['name']!r} ({cls.__name__})")
    return cls


def _decode_dataclass(kind, values, path, base):
    if not isinstance(values, dict):
        raise ConfigError(path, f"expected {describe(kind)}, got {values!r}")
    cls = _config_class(kind, values, path, base)
    if base is not _MISSING and type(base) is not cls:
        base = _MISSING
    upgrade = getattr(cls, "upgrade_json", None)
    if upgrade is not None:
        values = upgrade(values)
    fields = dataclasses.fields(cls)
    names = [f.name for f in fields]
    for key in values:
        if key not in names:
            raise ConfigError(_join(path, str(key)), f"unknown field of {cls.__name__}; expected one of {names}")
    hints = typing.get_type_hints(cls)
    arguments = {}
    for field in fields:
        where = _join(path, field.name)
        default = getattr(base, field.name) if base is not _MISSING else _field_default(field)
        if not field.init:  # e.g. a registered name: fixed by the class
            fixed = encode(_field_default(field))
            if field.name in values and values[field.name] != fixed:
                raise ConfigError(where, f"expected {fixed!r} in a {cls.__name__}, got {values[field.name]!r}")
        elif field.name in values:
            arguments[field.name] = decode(hints[field.name], values[field.name], where, default)
        elif default is _MISSING:
            raise ConfigError(where, f"missing: a {cls.__name__} has no default for it")
        else:
            arguments[field.name] = default
    try:
        return cls(**arguments)
    except ValueError as error:  # the dataclass's own checks, which name the field inside it
        raise ConfigError(path, str(error)) from None


def check_finite(values: Any, path: str = "") -> None:
    """ConfigError naming the first number of the JSON values ``values`` (``encode``'s) that is NaN or
    infinite: what ``decode`` refuses, for a config built in Python."""
    if isinstance(values, float) and not math.isfinite(values):
        raise ConfigError(path, f"expected a finite number, got {values!r}")
    items = values.items() if isinstance(values, dict) else enumerate(values) if isinstance(values, list) else ()
    for key, value in items:
        check_finite(value, _join(path, str(key)))


def _field_default(field: dataclasses.Field) -> Any:
    if field.default is not _MISSING:
        return field.default
    return field.default_factory() if field.default_factory is not _MISSING else _MISSING


def override(config: Any, assignments: Sequence[str]) -> Any:
    """``config`` with each ``"dotted.name=VALUE"`` of ``assignments`` applied in order (see the module
    docstring), checked whole; ConfigError naming the dotted name of what does not fit."""
    values = encode(config)
    for assignment in assignments:
        name, equals, text = assignment.partition("=")
        name = name.strip()
        if not equals or not name:
            raise ConfigError("", f"expected NAME=VALUE with a dotted field name (e.g. train.optim.lr=1e-3), "
                              f"got {assignment!r}")
        *parents, last = name.split(".")
        kind, holder, path = type(config), values, ""
        for key in parents:
            kind, holder, path = _member(kind, holder, key, path)
        field_kind, current, where = _member(kind, holder, last, path)
        new = _parse(field_kind, text, where, current)
        if isinstance(holder, list):
            holder[int(last)] = new
        else:
            holder[last] = new
    return decode(type(config), values)


def parse(kind: Any, text: str, path: str = "") -> Any:
    """``text`` (one ``--set`` VALUE) read as the type ``kind`` as ``override`` reads a field's (``none``,
    ``true`` / ``false``, numbers, comma-separated lists, JSON); ConfigError naming ``path`` otherwise."""
    return decode(kind, _parse(kind, text, path, None), path)


def _member(kind, holder, key, path):
    """``(type, JSON value, dotted name)`` of member ``key`` of ``holder``, the JSON value of type ``kind``."""
    where = _join(path, key)
    if holder is None:
        raise ConfigError(path, f"is none; give it whole first ({path}=...)")
    kind = _not_none(kind)
    if typing.get_origin(kind) is tuple and isinstance(holder, list):
        if not key.isdigit() or int(key) >= len(holder):
            raise ConfigError(where, f"expected an index below {len(holder)} of {path}")
        args = typing.get_args(kind)
        return (args[0] if len(args) == 2 and args[1] is Ellipsis else args[int(key)]), holder[int(key)], where
    if dataclasses.is_dataclass(kind) and isinstance(holder, dict):
        cls = _config_class(kind, holder, path, _MISSING)
        fields = {f.name: f for f in dataclasses.fields(cls)}
        if key not in fields:
            raise ConfigError(where, f"unknown field of {cls.__name__}; expected one of {list(fields)}")
        if not fields[key].init:  # a registered name: it picks the class, so the class is given whole
            raise ConfigError(where, f"is fixed by the class ({cls.__name__}'s is {holder.get(key)!r}); give "
                              f"{path} whole to pick another, e.g. {path}=NAME or {path}={{\"{key}\": NAME, ...}}")
        return typing.get_type_hints(cls)[key], holder.get(key), where
    raise ConfigError(where, f"{path or 'the config'} is {describe(kind)}, which has no member {key!r}")


def _options(kind) -> tuple:
    """The types a union ``kind`` allows (``(kind,)`` for any other type)."""
    return typing.get_args(kind) if typing.get_origin(kind) in (typing.Union, types.UnionType) else (kind,)


def _not_none(kind):
    """``X`` for ``X | None``, else ``kind``."""
    others = [option for option in _options(kind) if option is not type(None)]
    return others[0] if len(others) == 1 else kind


def _parse(kind, text: str, path: str, current: Any) -> Any:
    """The JSON value of ``text`` as the field type ``kind`` (``current``: the field's JSON value now)."""
    stripped = text.strip()
    if stripped[:1] in ("{", "["):
        try:
            given = json.loads(stripped)
        except ValueError as error:
            raise ConfigError(path, f"expected JSON, got {text!r} ({error})") from None
        return _merged(kind, current, given) if isinstance(current, dict) and isinstance(given, dict) else given
    parsed = _parse_plain(kind, stripped, text)
    if parsed is _MISSING:
        raise ConfigError(path, f"expected {describe(kind)}, got {text!r}")
    return parsed


def _merged(kind, current: dict, given: dict) -> dict:
    """The config object ``current`` of type ``kind`` with the fields ``given`` sets, nested configs
    merged alike; ``given`` itself where it names another class of a registered family."""
    cls = _not_none(kind)
    if hasattr(cls, "class_named"):
        if given.get("name", current.get("name")) != current.get("name"):
            return given
        cls = cls.class_named(current["name"])
    hints = typing.get_type_hints(cls) if dataclasses.is_dataclass(cls) else {}
    merged = dict(current)
    for key, value in given.items():
        both = isinstance(current.get(key), dict) and isinstance(value, dict) and key in hints
        merged[key] = _merged(hints[key], current[key], value) if both else value
    return merged


def _parse_plain(kind, stripped: str, text: str) -> Any:
    """``text`` read as ``kind`` without JSON brackets, or ``_MISSING`` when it cannot be."""
    if len(_options(kind)) > 1:
        if stripped.lower() in _NONE_WORDS and type(None) in _options(kind):
            return None
        readings = (_parse_plain(option, stripped, text) for option in _options(kind) if option is not type(None))
        return next((reading for reading in readings if reading is not _MISSING), _MISSING)
    origin = typing.get_origin(kind)
    if origin is tuple or kind is tuple:
        args = typing.get_args(kind)
        items = [] if not stripped else [item.strip() for item in stripped.split(",")]
        kinds = [args[0]] * len(items) if len(args) == 2 and args[1] is Ellipsis else list(args or [str] * len(items))
        if len(kinds) != len(items):
            return _MISSING
        parsed = [_parse_plain(item_kind, item, item) for item_kind, item in zip(kinds, items)]
        return _MISSING if any(item is _MISSING for item in parsed) else parsed
    if origin is typing.Literal or (isinstance(kind, type) and issubclass(kind, enum.Enum)):
        choices = typing.get_args(kind) if origin is typing.Literal else tuple(member.value for member in kind)
        return next((choice for choice in choices if str(choice) == stripped), _MISSING)
    if isinstance(kind, type) and hasattr(kind, "class_named"):
        return {"name": stripped}  # a registered config by name, with its defaults
    if kind is bool:
        return _BOOLS.get(stripped.lower(), _MISSING)
    if kind in (int, float):
        try:
            return kind(stripped)
        except ValueError:
            return _MISSING
    if kind is str or kind is Any:
        return text
    return _MISSING
