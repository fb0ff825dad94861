"""The application's batches scored by the registered methods (``jaxanom.method_registry``).

Batches of ``evaluate.predictions``, ``predict`` and the MMF pipeline hold the network's outputs
as ``{"logits", "attention_up"?, "attention_positions"?, "image"?, "mmf_maps"?}``; ``inputs_of``
gives them to the methods under the registry's ``INPUTS`` names, ``run_inputs`` says before any
work what a run's batches will hold, and ``score_all`` scores one batch with several methods.
"""
from __future__ import annotations

from typing import Iterable, Mapping

import numpy as np

from jaxanom.method_registry import INPUTS, call, check, get, given, load_plugin, names, posts
from jaxanom.void_methods import VOID_CHANNEL, without_channel

__all__ = ["INPUTS", "check", "describe", "get", "inputs_of", "load_plugin", "names", "provided", "run_inputs",
           "score_all", "without_channel"]


def inputs_of(batch: Mapping, stats=None) -> dict:
    """The method inputs of one batch ``{"logits", "attention_up"?, "attention_positions"?, "image"?,
    "mmf_maps"?}`` and the SML ``stats`` ``(mean, std)`` (None: none)."""
    inputs = {"logits": batch["logits"]}
    if np.shape(batch["logits"])[-1] == VOID_CHANNEL + 1:
        inputs["void_channel"] = VOID_CHANNEL
    if stats is not None:
        inputs["stats"] = stats
    if "attention_up" in batch:
        inputs["attention"] = batch["attention_up"]
        inputs["attention_positions"] = batch.get("attention_positions")
    for key in ("image", "mmf_maps"):
        if key in batch:
            inputs[key] = batch[key]
    return inputs


def provided(*, classes: int | None, stats: bool, attention: bool = False, images: bool = False,
             mmf_maps: bool = False) -> set[str]:
    """The inputs ``inputs_of`` will give for batches of logits with ``classes`` channels (None:
    unknown), with class statistics, attention maps, images or MMF's maps if so told."""
    flags = {"stats": stats, "attention": attention, "image": images, "mmf_maps": mmf_maps,
             "void_channel": classes == VOID_CHANNEL + 1}
    return {"logits", *(key for key, given in flags.items() if given)}


def run_inputs(experiment, *, stats: bool) -> set[str]:
    """The inputs every batch of a run's network (``experiment``: its ``Experiment``) will give
    with the frames' images, and class statistics if ``stats``; an attention module's outputs give
    the inputs its registration names (``method_inputs``)."""
    from jaxanom.models.attention import get

    module_inputs = get(experiment.attention).method_inputs if experiment.attention is not None else frozenset()
    return provided(classes=experiment.num_classes, stats=stats, attention="attention" in module_inputs,
                    images=True)


def score_all(method_names: Iterable[str], inputs: Mapping, options: Mapping[str, Mapping] | None = None, *,
              drop_void: bool = False) -> tuple[dict, dict]:
    """``(scores, used)``: each method's scores (B, H, W) of ``inputs`` and the options it used
    (``Method.options``: defaults, its own of ``options`` (``{method: {option: value}}``),
    resolved for this batch). ``drop_void``: the
    methods that do not read the void channel score the logits without it (a protocol's choice,
    ``jaxanom.protocols``); the ``void`` method still reads every channel. Each method is
    called through ``method_registry.call`` (its own read-only copy of the inputs; its output's
    shape and dtype checked); the caller checks the values where it reads them
    (``method_registry.check_finite``)."""
    method_names = check(method_names, given(inputs), options)
    without_void = _without_void(inputs) if drop_void and inputs.get("void_channel") is not None else inputs
    scores, used = {}, {}
    for name in method_names:
        method = get(name)
        method_inputs = inputs if "void_channel" in method.needs else without_void
        scores[name], used[name] = call(method, method_inputs, (options or {}).get(name))
    return scores, used


def _without_void(inputs: Mapping) -> dict:
    """``inputs`` whose logits lack the void channel (and so no ``void_channel``)."""
    return {**{k: v for k, v in inputs.items() if k != "void_channel"},
            "logits": without_channel(inputs["logits"], int(inputs["void_channel"]))}


def describe(unavailable: Iterable[str] = ()) -> str:
    """Every method, one per line: its name and description (the commands' ``--help``), and its
    options with their types and defaults, but those that need an input of ``unavailable``; then
    the post-processors any method composes with."""
    from jaxanom.config_codec import describe as described

    known = [name for name in names() if not get(name).needs & set(unavailable)]
    rows = []
    for name in known:
        method = get(name)
        options = "; ".join(f"{option}: {described(method.types[option])}, default {default}"
                            for option, default in method.defaults.items())
        rows.append((name, method.description + (f" (options {options})" if options else "")))
    rows += [(f"NAME+{post.name}", f"any method NAME, then {post.description}") for post in posts()
             if not post.needs & set(unavailable)]
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"  {name.ljust(width)}  {text}" for name, text in rows)
