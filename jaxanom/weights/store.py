"""VGG weights on disk, and starting a network from another one's modules.

A VGG has no run folder: ``write_vgg`` / ``read_vgg`` keep its variables in an .npz with the Flax
paths as names (``params/conv1_1/kernel``) and the configuration in ``vgg.json``.
``take_modules(fresh, source, modules, keep)`` starts a network from another's top-level modules
(but the layers ``keep``: a new head).
(Run folders of converted DeepLabV3+ / ESPNet weights: ``jaxanom.app.runs.write_run``.)
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from flax import traverse_util

from jaxanom.io import write_bytes_atomic, write_json_atomic

VGG_FILE, VGG_CONFIG = "vgg.npz", "vgg.json"


def write_vgg(folder: str | os.PathLike, model, variables: dict) -> None:
    """``variables`` of a ``jaxanom.models.vgg.VGG`` as ``vgg.npz`` plus ``vgg.json``."""
    import io

    folder = Path(folder)
    flat = {"/".join(path): np.asarray(value) for path, value in traverse_util.flatten_dict(variables).items()}
    buffer = io.BytesIO()
    np.savez(buffer, **flat)
    write_bytes_atomic(folder / VGG_FILE, buffer.getvalue())
    write_json_atomic(folder / VGG_CONFIG, {"config": model.config, "widths": list(model.widths)})


def read_vgg(folder: str | os.PathLike):
    """``(VGG model, variables)`` written by ``write_vgg``; ValueError when the folder has none."""
    import json

    from jaxanom.models.vgg import VGG

    folder = Path(folder)
    if not (folder / VGG_FILE).is_file() or not (folder / VGG_CONFIG).is_file():
        raise ValueError(f"folder: expected {VGG_FILE} and {VGG_CONFIG} (from convert-weights), in {os.fspath(folder)!r}")
    config = json.loads((folder / VGG_CONFIG).read_text())
    with np.load(folder / VGG_FILE, allow_pickle=False) as loaded:
        flat = {tuple(name.split("/")): loaded[name] for name in loaded.files}
    return VGG(config["config"], widths=tuple(config["widths"])), traverse_util.unflatten_dict(flat)


def take_modules(fresh: dict, source: dict, modules: Sequence[str] | None = None, keep: Sequence[str] = ()) -> dict:
    """``fresh`` variables with the top-level modules ``modules`` (default: all of ``source``'s)
    replaced by ``source``'s, e.g. ``("backbone",)`` to start from an ImageNet trunk; the layers
    ``keep`` (module paths inside them, ``"decoder/output_conv"``: a new head) stay ``fresh``'s.

    Each taken module must have the same variables with the same shapes in both (but in ``keep``);
    a mismatch, or a module that one side lacks, raises ValueError naming it. Other modules keep
    ``fresh``.
    """
    names = sorted({name for tree in source.values() for name in tree}) if modules is None else list(modules)
    have = {name for tree in fresh.values() for name in tree}
    problems = [f"{name} (not in the network)" for name in names if name not in have]
    problems += [f"{name} (not in the source)" for name in names
                 if name in have and not any(name in tree for tree in source.values())]
    layers = {"/".join(path[:-1]) for tree in fresh.values() for path in traverse_util.flatten_dict(tree)}
    problems += [f"{layer} (kept, not a layer of the network)" for layer in keep
                 if not any(f"{path}/".startswith(f"{layer}/") for path in layers)]
    kept = tuple(tuple(layer.split("/")) for layer in keep)
    out = {collection: dict(tree) for collection, tree in fresh.items()}
    for collection, tree in fresh.items():
        for name in names:
            if name not in tree or problems:
                continue
            want = _without(traverse_util.flatten_dict(tree[name]), name, kept)
            got = _without(traverse_util.flatten_dict(source.get(collection, {}).get(name, {})), name, kept)
            differ = [f"{collection}/{name}/{'/'.join(path)} (not in the source)" for path in want if path not in got]
            differ += [f"{collection}/{name}/{'/'.join(path)}: source {np.shape(got[path])}, network "
                       f"{np.shape(want[path])}" for path in want
                       if path in got and np.shape(got[path]) != np.shape(want[path])]
            differ += [f"{collection}/{name}/{'/'.join(path)} (not in the network)" for path in got if path not in want]
            problems += differ
            if not differ:  # the source's variables, the kept layers' fresh ones
                out[collection][name] = traverse_util.unflatten_dict(
                    {path: got.get(path, value) for path, value in traverse_util.flatten_dict(tree[name]).items()})
    if problems:
        shown = "; ".join(problems[:8]) + (f"; ... and {len(problems) - 8} more" if len(problems) > 8 else "")
        raise ValueError(f"init modules {names}: the source does not fit the network: {shown}")
    return out


def _without(flat: dict, module: str, kept: Sequence[tuple[str, ...]]) -> dict:
    """The flattened variables of top-level ``module`` outside the layers ``kept`` (full paths)."""
    return {path: value for path, value in flat.items()
            if not any((module, *path)[:len(layer)] == layer for layer in kept)}
