"""Reading PyTorch state dicts without unpickling arbitrary objects.

    state = read_state_dict("model.pth")          # torch.load(weights_only=True); needs torch
    state = read_state_dict("model.safetensors")  # the safetensors package, no torch
    state = read_state_dict("model.npz")          # NumPy, no torch

The result is ``{name: float32 np.ndarray}`` in PyTorch's layout (convolutions OIHW). A training
checkpoint (a dict holding ``"state_dict"``, ``"model"``, ``"model_state_dict"`` or ``"net"`` beside
optimizer state) gives that state dict;
DataParallel's ``module.`` prefix is removed. Integer entries (BatchNorm's
``num_batches_tracked``) are kept as they are. Quantised tensors (``torch.qint8`` and the like, e.g.
an int8 redistribution of a network) are dequantised with torch's own ``Tensor.dequantize()``
(scale and zero point per tensor or per channel) to float32. A file that cannot be read raises ValueError
naming it; a ``.pth`` file holding anything but tensors, numbers, strings and containers is refused
by ``weights_only`` and never unpickled.
"""
from __future__ import annotations

import os
import pickle
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

_DATA_PARALLEL = "module."
_WRAPPERS = ("state_dict", "model", "model_state_dict", "net")  # where training scripts keep the weights


def read_state_dict(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The state dict stored in ``path`` (.pth/.pt/.ckpt/.bin via torch, .npz, .safetensors)."""
    file = Path(path)
    if not file.is_file():
        raise ValueError(f"weights file: expected an existing file, got {os.fspath(path)!r}")
    suffix = file.suffix.lower()
    if suffix == ".npz":
        return state_dict_arrays(_read_npz(file), file)
    if suffix == ".safetensors":
        return state_dict_arrays(_read_safetensors(file), file)
    return state_dict_arrays(_read_torch(file), file)


def state_dict_arrays(state: Mapping, source: object = "state_dict") -> dict[str, np.ndarray]:
    """``state`` (tensors or arrays by name, or a checkpoint holding ``"state_dict"``) as NumPy.

    Floating tensors become float32 arrays, quantised ones are dequantised; ``module.`` prefixes are removed.
    """
    if not isinstance(state, Mapping):
        raise ValueError(f"{source}: expected a mapping of parameter names to tensors, got {type(state).__name__}")
    for key in _WRAPPERS:  # a training checkpoint: {"state_dict": ..., "optimizer": ...}, {"model": ...}
        if isinstance(state.get(key), Mapping):
            state = state[key]
            break
    arrays = {}
    for name, value in state.items():
        if not isinstance(name, str):
            raise ValueError(f"{source}: expected parameter names as strings, got {name!r}")
        key = name[len(_DATA_PARALLEL):] if name.startswith(_DATA_PARALLEL) else name
        if key in arrays:
            raise ValueError(f"{source}: {key!r} appears both with and without the 'module.' prefix")
        arrays[key] = _to_numpy(value, f"{source}: {name}")
    if not arrays:
        raise ValueError(f"{source}: expected parameters, found an empty state dict")
    return arrays


def _to_numpy(value, where: str) -> np.ndarray:
    if hasattr(value, "detach"):  # a torch.Tensor; bfloat16 / float16 go through float32
        if str(getattr(value, "layout", "torch.strided")) != "torch.strided":
            raise ValueError(f"{where}: a {str(value.layout).replace('torch.', '')} tensor; expected dense tensors "
                             "(save tensor.to_dense())")
        value = value.detach().cpu()
        if value.is_quantized:  # integers with a scale and zero point: torch's own arithmetic gives the floats
            value = value.dequantize()
        value = value.float() if value.is_floating_point() else value
        value = value.numpy()
    array = np.asarray(value) if isinstance(value, (np.ndarray, np.generic, int, float)) else None
    if array is None or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{where}: expected a numeric tensor, got {type(value).__name__}")
    return array.astype(np.float32) if np.issubdtype(array.dtype, np.floating) else array


def _read_npz(file: Path) -> dict:
    try:
        with np.load(file, allow_pickle=False) as loaded:
            return {name: loaded[name] for name in loaded.files}
    except Exception as error:  # zipfile, OSError, ValueError (pickled arrays) all mean "not readable"
        raise ValueError(f"weights file {file}: not a readable .npz ({type(error).__name__}: {error})") from None


def _read_safetensors(file: Path) -> dict:
    try:
        from safetensors.numpy import load_file
    except ImportError:
        raise ValueError(f"weights file {file}: reading .safetensors needs the safetensors package "
                         "(pip install 'jaxanom[torch]' or safetensors)") from None
    try:
        return load_file(file)
    except Exception as error:  # SafetensorError, OSError, TypeError (bfloat16 in NumPy)
        raise ValueError(f"weights file {file}: not a readable .safetensors file "
                         f"({type(error).__name__}: {error})") from None


def _read_torch(file: Path) -> Mapping:
    try:
        import torch
    except ImportError:
        raise ValueError(f"weights file {file}: reading PyTorch checkpoints needs torch (pip install "
                         "'jaxanom[torch]'), or save the state dict as .npz or .safetensors elsewhere") from None
    try:
        with warnings.catch_warnings():  # torch's own deprecation notes while it rebuilds quantised tensors
            warnings.filterwarnings("ignore", message=r"(?s).*(TypedStorage is deprecated|quantize_per_tensor.*"
                                    r"deprecated)", category=UserWarning)
            return torch.load(file, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:  # objects only unpickling (running code) builds, or damage
        unsafe = _unsafe_globals(file)
        if unsafe:
            raise ValueError(f"weights file {file}: refused: it holds Python objects besides tensors (globals "
                             f"{', '.join(unsafe[:5])}), and jaxanom never runs code from a weights file; save the "
                             "state dict alone (torch.save(model.state_dict(), path)) or as .safetensors") from None
        detail = re.search(r"WeightsUnpickler error:\s*(\S[^\n]*)", _plain(error))
        raise ValueError(f"weights file {file}: not a readable PyTorch checkpoint (damaged, or not a weights file: "
                         f"{detail.group(1) if detail else 'UnpicklingError'})") from None
    except Exception as error:  # RuntimeError / EOFError (damaged, truncated)
        first = _plain(error).splitlines()[0] if _plain(error) else ""
        raise ValueError(f"weights file {file}: not a readable PyTorch checkpoint ({type(error).__name__}: {first})"
                         ) from None


def _unsafe_globals(file: Path) -> list[str]:
    """The globals (``module.name``) that the pickle of the ``torch.save`` file ``file`` references
    and ``torch.load(weights_only=True)`` does not build: torch's own scan of the pickle's opcodes,
    nothing run, so a refusal is told from damage whatever torch's message says. [] where the scan
    cannot read the file (damaged, or torch's legacy non-zip format)."""
    from torch.serialization import get_unsafe_globals_in_checkpoint

    try:
        return get_unsafe_globals_in_checkpoint(file)
    except Exception:  # ValueError (not a zip checkpoint), RuntimeError / pickle errors (damage)
        return []


def _plain(error: Exception) -> str:
    """An error's message without terminal colour codes."""
    return re.sub(r"\x1b\[[0-9;]*m", "", str(error)).strip()
