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
``cudam.objective.CuDAM``, ``msaam.objective.MSAAM``; ``jaxanom.builtins`` lists the modules); a
user's own is registered with
``@register`` in a module of its own (a plug-in: ``--plugin MODULE``, or an installed package's
``jaxanom.objectives`` entry point) and then stored in and read back from a run's
``experiment.json`` like those; the run records that module (``Experiment.plugins``) so that every
later reading of it imports it. The registry is a ``jaxanom.registry.Registry`` (``OBJECTIVES``),
the type every kind of plug-in uses: names follow its ``NAME_RULE``, a taken name is refused.
"""
from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from jaxanom import builtins, registry

ENTRY_POINTS = "jaxanom.objectives"
OBJECTIVES: registry.Registry[type["Objective"]] = registry.Registry(
    "objective", ENTRY_POINTS, lambda: builtins.MODULES, lambda cls, origin: f"{cls.__qualname__} ({origin})")


@dataclasses.dataclass(frozen=True)
class Objective:
    """Base class of training objectives (see the module docstring for the contract)."""

    needs: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def class_named(cls, name: str) -> type["Objective"]:
        """The objective class registered as ``name`` (how ``config_codec`` reads an objective back);
        ValueError listing the known names otherwise."""
        found = OBJECTIVES.find(name)
        if found is None:
            raise ValueError(f"expected one of {OBJECTIVES.names()}, got {name!r} (an objective of a plug-in: import "
                             f"its module first, e.g. with --plugin MODULE){OBJECTIVES.broken_note()}")
        return found

    def init_state(self, num_classes: int) -> Any:
        """The state carried in the train state for a network of ``num_classes`` outputs; None: none."""
        return None

    def loss(self, outputs: dict, batch: dict, key, state: Any, ignore: int) -> tuple[Any, dict, Any]:
        raise NotImplementedError

    def describe(self, outputs: dict) -> str | None:
        """A line ``train`` prints before it starts, given the shapes of the network's outputs on one
        training crop (e.g. CuDAM's reward weight at its attention map's size); None: nothing."""
        return None

    @classmethod
    def from_legacy_loss(cls, loss: dict, own_terms: bool) -> "Objective":
        """This objective from the ``train.loss`` of a run of an earlier jaxanom (one dict with every
        paper's settings, read by ``app.experiment.legacy_objective``); ``own_terms=False``: its own
        terms off, so the loss is exactly the cross-entropy. Only jaxanom's own objectives existed then."""
        raise ValueError(f"train.loss.method: expected an objective of an earlier jaxanom, got {cls.__name__}")


def legacy_class_weights(loss: dict) -> tuple[float, ...] | None:
    """The ``class_weights`` of a legacy ``train.loss`` (``Objective.from_legacy_loss``)."""
    return tuple(loss["class_weights"]) if loss.get("class_weights") is not None else None


def register(cls: type[Objective]) -> type[Objective]:
    """Class decorator: make ``cls`` (a frozen ``Objective`` dataclass with a ``name`` field
    default) known by that name, registered by its module. ValueError in one line when the name
    is not a name (``registry.NAME_RULE``) or another class holds it."""
    fields = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
    if not issubclass(cls, Objective) or "name" not in fields or not isinstance(fields["name"].default, str):
        raise ValueError(f"objective {cls.__name__}: expected an Objective dataclass with a field "
                         f"`name: str = dataclasses.field(default=..., init=False)`")
    OBJECTIVES.add(fields["name"].default, cls, cls.__module__)
    return cls


def objective_names() -> tuple[str, ...]:
    """The names of every registered objective, jaxanom's own first."""
    return OBJECTIVES.names()
