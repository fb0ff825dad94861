"""Filling Flax variables from a PyTorch state dict, all or nothing.

A *naming* maps the path of each convolution or BatchNorm module (flax's or ``jaxanom.nn``'s; e.g.
``("backbone", "layer1_0", "conv1", "conv")``) to the PyTorch module that holds its weights
(``"layer1.0.conv1"``), or to None when the checkpoint does not provide it. Leaves map as::

    Conv      kernel (kh, kw, I, O) <- weight (O, I, kh, kw)     bias <- bias
    BatchNorm scale <- weight, bias <- bias (params); mean <- running_mean, var <- running_var
              (batch_stats); num_batches_tracked is not used (eval maths needs only the above)
    PReLU     slope <- weight

A module with a ``kernel`` (kh, kw, A, B) takes a PyTorch weight (B, A, kh, kw): a Conv's
(O, I, kh, kw), or a 2x2 transposed conv's (I, O, kh, kw) when its Flax kernel is (kh, kw, O, I)
(``jaxanom.models.espnet.Upsample2``).

``in_shift[prefix] = s`` rotates a convolution's input channels (Flax channel c takes PyTorch
channel (c + s) mod I): two concatenations of the SML network put their branches in another order
than jaxanom's (see ``jaxanom.weights.architectures``). Every expected key must be present with
the expected shape and finite values, and every key of the checkpoint must be used or ignorable;
otherwise one ValueError lists the missing, unexpected and mis-shaped keys.
"""
from __future__ import annotations

import re
from collections.abc import Callable, Mapping

import numpy as np
from flax import traverse_util

_CONV = {"kernel": "weight", "bias": "bias"}
_BATCH_NORM = {"scale": "weight", "bias": "bias", "mean": "running_mean", "var": "running_var"}
_PRELU = {"slope": "weight"}
_SHOWN = 8  # keys listed per kind of problem


def fill_variables(state: Mapping[str, np.ndarray], template: Mapping, naming: Callable[[tuple], str | None],
                   ignorable: Callable[[str], bool], what: str, in_shift: Mapping[str, int] | None = None) -> dict:
    """Variables shaped like ``template`` (arrays or ShapeDtypeStructs) with the checkpoint's values.

    Leaves whose module ``naming`` maps to None keep the template's value (they must then be
    arrays). ``ignorable(key)`` accepts checkpoint keys that the Flax model has no use for
    (a classifier, an auxiliary head). ``what`` names the architecture in errors.
    """
    in_shift = in_shift or {}
    flat = {collection: traverse_util.flatten_dict(tree) for collection, tree in template.items()}
    conv_modules = {path[:-1] for path in flat.get("params", {}) if path[-1] == "kernel"}
    prelu_modules = {path[:-1] for path in flat.get("params", {}) if path[-1] == "slope"}
    expected = {}  # torch key -> (collection, flax path, rotation of input channels)
    for collection, tree in flat.items():
        for path in tree:
            prefix = naming(path[:-1])
            if prefix is None:
                continue
            module = path[:-1]
            leaf = (_CONV if module in conv_modules else _PRELU if module in prelu_modules else _BATCH_NORM)[path[-1]]
            expected[f"{prefix}.{leaf}"] = (collection, path, in_shift.get(prefix, 0))
    missing = sorted((key for key in expected if key not in state), key=_natural)
    unexpected = [key for key in state if key not in expected and not key.endswith(".num_batches_tracked")
                  and not ignorable(key)]
    values, misshaped, bad = {}, [], []
    for key, (collection, path, shift) in sorted(expected.items(), key=lambda item: _natural(item[0])):
        if key not in state:
            continue
        want = tuple(flat[collection][path].shape)
        torch_shape = (want[-1], want[-2], *want[:-2]) if path[-1] == "kernel" else want
        array = np.asarray(state[key])
        if array.shape != torch_shape:
            misshaped.append(f"{key}: checkpoint {array.shape}, expected {torch_shape}")
            continue
        if not np.issubdtype(array.dtype, np.floating):
            bad.append(f"{key} ({array.dtype}, expected floats)")
            continue
        if not np.isfinite(array).all():
            bad.append(f"{key} ({array.size - np.count_nonzero(np.isfinite(array))} NaN/Inf)")
            continue
        if path[-1] == "kernel":
            array = array.transpose(*range(2, array.ndim), 1, 0)
            if shift:
                array = np.roll(array, -shift, axis=-2)
        values[(collection, path)] = array.astype(np.float32)
    if missing or unexpected or misshaped or bad:
        raise ValueError(_report(what, len(expected), missing, unexpected, misshaped, bad))
    out = {}
    for collection, tree in flat.items():
        out[collection] = traverse_util.unflatten_dict(
            {path: values.get((collection, path), leaf) for path, leaf in tree.items()})
    return out


def _natural(key: str) -> list:
    """Sort key putting layer3.10 after layer3.9."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", key)]


def _report(what, expected, missing, unexpected, misshaped, bad) -> str:
    """One line (the command line prints errors as one line)."""
    parts = []
    for title, keys in (("missing", missing), ("unexpected", unexpected), ("mis-shaped", misshaped),
                        ("not finite floating-point tensors", bad)):
        if keys:
            shown = "; ".join(keys[:_SHOWN]) + (f"; ... and {len(keys) - _SHOWN} more" if len(keys) > _SHOWN else "")
            parts.append(f"{title} ({len(keys)}): {shown}")
    return f"state dict does not match {what} ({expected} tensors expected; nothing was loaded): " + ". ".join(parts)
