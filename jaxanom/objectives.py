"""Training objectives: what a train step minimises, as plug-ins the trainer is handed.

An objective is a frozen dataclass (its config) with

- ``name``: its registry name, a field (so ``config_codec.encode`` records it and reads it back);
- ``needs``: the model outputs it reads besides ``"logits"`` (e.g. ``("attention",)``); the
  trainer refuses a network that does not produce them before compiling anything;
- ``init_state(num_classes) -> pytree``: state it carries from step to step in the train state
  (``None``, the default, when it keeps none); the trainer treats it as opaque;
- ``loss(outputs, batch, key, state, ignore) -> (loss, aux, new_state)``: pure and jit-friendly.
  ``outputs`` is the model's dict with float32 ``"logits"`` (B, H, W, C); ``batch`` holds
  ``"label"`` (B, H, W) int with ``ignore`` on void pixels (and the model's extra inputs);
  ``key`` is this step's PRNG key; ``loss`` is a float32 scalar and ``aux`` a dict of scalars
  logged as ``train/<name>``.

Every objective jaxanom ships is registered next to its paper's code (``losses.CrossEntropy``,
``cudam_objective.CuDAM``, ``msaam_objective.MSAAM``); a user's own is registered with
``@register`` and then stored in and read back from a run's ``experiment.json`` like those.
"""
from __future__ import annotations

import dataclasses
import importlib
from typing import Any, ClassVar

from jaxanom.config_codec import decode

# the modules that register jaxanom's own objectives, imported on the first look-up
_BUILTIN_MODULES = ("jaxanom.losses", "jaxanom.cudam_objective", "jaxanom.msaam_objective")
_REGISTRY: dict[str, type["Objective"]] = {}


@dataclasses.dataclass(frozen=True)
class Objective:
    """Base class of training objectives (see the module docstring for the contract)."""

    needs: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def class_named(cls, name: str) -> type["Objective"]:
        """The objective class registered as ``name`` (how ``config_codec`` reads an objective back);
        ValueError listing the known names otherwise."""
        _load_builtins()
        if name not in _REGISTRY:
            raise ValueError(f"expected one of {tuple(_REGISTRY)}, got {name!r}")
        return _REGISTRY[name]

    def init_state(self, num_classes: int) -> Any:
        """The state carried in the train state for a network of ``num_classes`` outputs; None: none."""
        return None

    def loss(self, outputs: dict, batch: dict, key, state: Any, ignore: int) -> tuple[Any, dict, Any]:
        raise NotImplementedError


def register(cls: type[Objective]) -> type[Objective]:
    """Class decorator: make ``cls`` (a frozen ``Objective`` dataclass with a ``name`` field
    default) known by that name. ValueError when another class holds the name."""
    fields = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
    if not issubclass(cls, Objective) or "name" not in fields or not isinstance(fields["name"].default, str):
        raise ValueError(f"objective {cls.__name__}: expected an Objective dataclass with a field "
                         f"`name: str = dataclasses.field(default=..., init=False)`")
    name = fields["name"].default
    if _REGISTRY.get(name, cls) is not cls:
        raise ValueError(f"objective name {name!r}: already registered by {_REGISTRY[name].__qualname__}")
    _REGISTRY[name] = cls
    return cls


def _load_builtins() -> None:
    for module in _BUILTIN_MODULES:
        importlib.import_module(module)


def objective_names() -> tuple[str, ...]:
    """The names of every registered objective, jaxanom's own first."""
    _load_builtins()
    return tuple(_REGISTRY)


def objective_class(name: str) -> type[Objective]:
    """The objective class registered as ``name``; ValueError listing the known names otherwise."""
    try:
        return Objective.class_named(name)
    except ValueError as error:
        raise ValueError(f"objective: {error}") from None


def objective_from_dict(values: dict) -> Objective:
    """The inverse of ``config_codec.encode(objective)``: ``{"name": ..., field: value}``; a
    ``config_codec.ConfigError`` (a ValueError) naming the field on an unknown name or field."""
    return decode(Objective, values, "objective")
