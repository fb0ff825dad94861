"""Attention modules by name: add-ons a segmenter runs on one of its feature maps.

A paper's package registers its module (``register(AttentionModule(...))``, done when jaxanom's
built-in modules load, ``jaxanom.builtins``); a plug-in's module (``--plugin MODULE``, or the
entry-point group ``jaxanom.attention_modules``) registers its own the same way
(``ATTENTION_MODULES`` is a ``jaxanom.registry.Registry``); a segmenter (``DeepLabV3Plus``, ``ERFNet``,
``ESPNet``) names the positions it offers and, built with ``attention=NAME``, runs the module at
one of them::

    model = build_model("erfnet", num_classes=20, attention="cudam")      # at ERFNet's "deep" position
    model = build_model("deeplabv3plus_tiny", attention="cudam", attention_position="output",
                        attention_options=(("gate", "scale_free"),))

At its position the segmenter calls ``spec.attend(module, features, taps)`` with ``features``
(B, h, w, C) and ``taps``, its earlier feature maps by name (``"low"``: the stage at stride 4,
``"mid"``: the next one; see each segmenter), and carries on with the features returned (same
shape). The module's extra outputs (float32, e.g. CuDAM's ``"attention"`` map, MSAAM's
``"branch_weights"``) join the network's output dict, where objectives and scoring methods read
them. The module's parameters sit under its registered name (``params[name]``).
"""
from __future__ import annotations

import dataclasses
import sys
from typing import Any, Callable, Mapping

import flax.linen as nn

from jaxanom import builtins, registry

# one application of a module at a position: (module, features, taps) -> (features, outputs)
Attend = Callable[[nn.Module, Any, Mapping[str, Any]], tuple[Any, dict]]

ENTRY_POINTS = "jaxanom.attention_modules"


@dataclasses.dataclass(frozen=True)
class AttentionModule:
    """One registered attention module.

    ``name``: its registry name (also its parameters' module name). ``build(dtype=..., name=...,
    **options)``: the Flax module. ``attend(module, features, taps) -> (features, outputs)``: one
    application at a position (module docstring). ``positions``: the segmenter positions where it
    may sit, preferred first: a segmenter runs it at the first of them it offers unless told a
    position. ``options``: the defaults of ``build``'s keyword options. ``objective``: the
    registered name of the training objective of its paper (``jaxanom.objectives``), which reads
    its outputs. ``method_inputs``: the scoring-method inputs (``jaxanom.method_registry.INPUTS``)
    its outputs give (``"attention"`` for a map the ``cudam`` method reads). ``recorded_as``:
    ``{option or "position": Experiment field}``, the run fields that record its position and
    options (named as earlier versions wrote them, so old runs read back unchanged).
    """

    name: str
    build: Callable[..., nn.Module]
    attend: Attend
    positions: tuple[str, ...]
    options: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    objective: str = "cross_entropy"
    method_inputs: frozenset[str] = frozenset()
    recorded_as: Mapping[str, str] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if not self.positions:
            raise ValueError(f"attention module {self.name!r}: expected at least one position, got none")


ATTENTION_MODULES: registry.Registry[AttentionModule] = registry.Registry(
    "attention module", ENTRY_POINTS, lambda: builtins.MODULES)


def register(module: AttentionModule) -> AttentionModule:
    """Make ``module`` known by its name; ValueError in one line when the name is not a name or
    another module holds it (``registry.Registry.add``)."""
    if not isinstance(module, AttentionModule):
        raise ValueError(f"attention module: expected a jaxanom.models.attention.AttentionModule, "
                         f"got {type(module).__name__}")
    return ATTENTION_MODULES.add(module.name, module, sys._getframe(1).f_globals.get("__name__", "?"))


def attention_names() -> tuple[str, ...]:
    """The names of every registered attention module, jaxanom's own first."""
    return ATTENTION_MODULES.names()


def get(name: str) -> AttentionModule:
    """The attention module registered as ``name``; ValueError naming ``attention`` otherwise."""
    found = ATTENTION_MODULES.find(name)
    if found is None:
        raise ValueError(f"attention: expected None or one of {attention_names()}, got {name!r} (a plug-in's: "
                         f"import its module first, e.g. with --plugin MODULE){ATTENTION_MODULES.broken_note()}")
    return found


def resolve_position(attention: str | None, position: str | None, offered: tuple[str, ...]) -> str | None:
    """Where ``attention`` sits on a segmenter offering the positions ``offered``: ``position``, or
    (None) the first of the module's positions the segmenter offers; None without a module.
    ValueError naming ``attention`` or ``attention_position`` when they do not fit."""
    if attention is None:
        if position is not None:
            raise ValueError(f"attention_position: expected None without an attention module, got {position!r}")
        return None
    spec = get(attention)
    fitting = tuple(p for p in spec.positions if p in offered)
    if not fitting:
        raise ValueError(f"attention: {attention!r} sits at {spec.positions}, this segmenter offers {offered}")
    if position is None:
        return fitting[0]
    if position not in fitting:
        raise ValueError(f"attention_position: expected one of {fitting} for {attention!r} on this segmenter, "
                         f"got {position!r}")
    return position


def check_attachment(segmenter) -> None:
    """ValueError unless ``segmenter``'s ``attention``, ``attention_position`` and
    ``attention_options`` fit its ``ATTENTION_POSITIONS`` (its ``__post_init__`` calls this)."""
    resolve_position(segmenter.attention, segmenter.attention_position, segmenter.ATTENTION_POSITIONS)
    options = dict(segmenter.attention_options)
    spec = get(segmenter.attention) if segmenter.attention is not None else None
    known = set(spec.options) if spec else set()
    if set(options) - known:
        raise ValueError(f"attention_options: {segmenter.attention!r} has the options {tuple(sorted(known))}, "
                         f"got {sorted(set(options) - known)}")
    if spec:  # the module's own checks of its options, on a module of no parent (nothing is built)
        spec.build(dtype=segmenter.dtype, parent=None, **{**spec.options, **options})


class Attachment:
    """The attention module of a segmenter inside its ``nn.compact`` ``__call__``:
    ``at(position, features, taps, out)`` runs it there (adding its outputs to ``out``) and
    returns the features, unchanged at any other position. Made once per call, so one module
    (one set of parameters) serves the position it sits at."""

    def __init__(self, segmenter):
        self.position = resolve_position(segmenter.attention, segmenter.attention_position,
                                         segmenter.ATTENTION_POSITIONS)
        if self.position is not None:
            self.spec = get(segmenter.attention)
            options = {**self.spec.options, **dict(segmenter.attention_options)}
            self.module = self.spec.build(dtype=segmenter.dtype, name=self.spec.name, **options)

    def at(self, position: str, features, taps: Mapping[str, Any], out: dict):
        if position != self.position:
            return features
        features, outputs = self.spec.attend(self.module, features, taps)
        out.update(outputs)
        return features
