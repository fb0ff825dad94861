"""Training objectives: what a train step minimises, as plug-ins the trainer is handed.

An objective is a frozen dataclass (its config) with

- ``name``: its registry name, a field (so ``dataclasses.asdict`` records it);
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

# the modules that register jaxanom's own objectives, imported on the first look-up
_BUILTIN_MODULES = ("jaxanom.losses", "jaxanom.cudam_objective", "jaxanom.msaam_objective")
_REGISTRY: dict[str, type["Objective"]] = {}


@dataclasses.dataclass(frozen=True)
class Objective:
    """Base class of training objectives (see the module docstring for the contract)."""

    needs: ClassVar[tuple[str, ...]] = ()

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
    _load_builtins()
    if name not in _REGISTRY:
        raise ValueError(f"objective: expected one of {tuple(_REGISTRY)}, got {name!r}")
    return _REGISTRY[name]


def objective_from_dict(values: dict) -> Objective:
    """The inverse of ``dataclasses.asdict(objective)``: ``{"name": ..., field: value}`` (JSON lists
    become tuples). ValueError naming the objective on an unknown name or field."""
    if not isinstance(values, dict) or not isinstance(values.get("name"), str):
        raise ValueError(f"objective: expected an object with a 'name', got {values!r}")
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k != "name"}
    cls = objective_class(values["name"])
    try:
        return cls(**fields)
    except TypeError as error:  # an unknown field
        raise ValueError(f"objective {values['name']!r}: {error}") from None
