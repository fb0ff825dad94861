"""The application's batches scored by the registered methods (``jaxanom.method_registry``).

Batches of ``evaluate.predictions``, ``predict`` and the MMF pipeline hold the network's outputs
as ``{"logits", "attention_up"?, "attention_positions"?, "image"?, "mmf_maps"?}``; ``inputs_of``
gives them to the methods under the registry's ``INPUTS`` names, ``run_inputs`` says before any
work what a run's batches will hold, and ``score_all`` scores one batch with several methods.
"""
from __future__ import annotations

from typing import Iterable, Mapping

from jaxanom.method_registry import INPUTS, check, get, given, load_plugin, names

__all__ = ["INPUTS", "check", "describe", "get", "inputs_of", "load_plugin", "names", "run_inputs", "score_all"]


def inputs_of(batch: Mapping, stats=None) -> dict:
    """The method inputs of one batch ``{"logits", "attention_up"?, "attention_positions"?, "image"?,
    "mmf_maps"?}`` and the SML ``stats`` ``(mean, std)`` (None: none)."""
    inputs = {"logits": batch["logits"]}
    if stats is not None:
        inputs["stats"] = stats
    if "attention_up" in batch:
        inputs["attention"] = batch["attention_up"]
        inputs["attention_positions"] = batch.get("attention_positions")
    for key in ("image", "mmf_maps"):
        if key in batch:
            inputs[key] = batch[key]
    return inputs


def run_inputs(experiment, *, stats: bool, images: bool = True) -> set[str]:
    """The inputs every batch of a run's network will give (``experiment``: its ``Experiment``),
    with class statistics if ``stats`` and the images if ``images``."""
    provided = {"logits"}
    if stats:
        provided.add("stats")
    if experiment.attention == "cudam":
        provided.add("attention")
    if images:
        provided.add("image")
    return provided


def score_all(method_names: Iterable[str], inputs: Mapping, options: Mapping | None = None) -> tuple[dict, dict]:
    """``(scores, used)``: each method's scores (B, H, W) of ``inputs`` and the options it used
    (``Method.options``: defaults, ``options``, resolved for this batch)."""
    method_names = check(method_names, given(inputs), options)
    scores, used = {}, {}
    for name in method_names:
        method = get(name)
        used[name] = method.options(inputs, options)
        scores[name] = method.score(inputs, used[name])
    return scores, used


def describe() -> str:
    """Every method, one per line: its name and description (the commands' ``--help``)."""
    known = names()
    width = max(map(len, known))
    return "\n".join(f"  {name.ljust(width)}  {get(name).description}" for name in known)
