"""ESPNet (p=2, q=8, light decoder) forward pass at 1024x512, batch 1 and 8, against PyTorch.

The peer is the PyTorch rendering that the exactness tests check against the authors' checkpoint
(``tests/torch_reference.py``), eval mode, no gradients; both carry the same weights (the
authors' Cityscapes checkpoint when ../shared/realdata has it, else the peer's random ones),
imported with ``jaxanom.weights.from_torch``. float32 on both (on a GPU: PyTorch channels-last).
``ratio`` = PyTorch ms / jaxanom ms (above 1: jaxanom is faster). ``quick`` runs 64x128 without
the peer: a smoke test of the code path.

    PYTHONPATH=. python benchmarks/bench_espnet.py [--quick]
"""
from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.timing import environment, flop_rate, markdown_table, median_ms
from jaxanom.models import ESPNet
from jaxanom.weights import from_torch

ROOT = Path(__file__).resolve().parent.parent
CHECKPOINT = Path(os.environ.get("JAXANOM_REALDATA", ROOT.parent / "shared" / "realdata")) / "espnet" / "espnet_p_2_q_8.pth"


def _sizes(quick: bool) -> dict:
    if quick:
        return {"shapes": [(1, 64, 128)], "repeats": 3}
    return {"shapes": [(1, 512, 1024), (8, 512, 1024)], "repeats": 10 if jax.default_backend() == "gpu" else 3}


def _torch_net():
    """The peer with the authors' weights (or random ones), and its state dict; None without torch."""
    try:
        import torch
    except ImportError:
        return None
    spec = importlib.util.spec_from_file_location("torch_reference", ROOT / "tests" / "torch_reference.py")
    reference = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(reference)
    net = reference.ESPNetTorch(classes=20, p=2, q=8)
    if CHECKPOINT.is_file():
        net.load_state_dict(torch.load(CHECKPOINT, map_location="cpu", weights_only=True))
    return net.eval()


def _jax_ms(model, variables, shape, repeats):
    images = jnp.asarray(np.random.default_rng(0).normal(size=(*shape, 3)).astype(np.float32))
    forward = jax.jit(lambda v, x: model.apply(v, x, train=False)["logits"])
    ms = median_ms(lambda: forward(variables, images), repeats=repeats, warmup=2)
    return ms, flop_rate(forward, variables, images, ms=ms)


def _torch_ms(net, shape, repeats):
    import torch

    device = "cuda" if torch.cuda.is_available() else "cpu"
    fmt = torch.channels_last if device == "cuda" else torch.contiguous_format
    net = net.to(device, memory_format=fmt)
    x = torch.randn(shape[0], 3, *shape[1:], device=device).to(memory_format=fmt)

    def forward():
        with torch.no_grad():
            return net(x)

    return median_ms(forward, repeats=repeats, warmup=2)


def run(quick: bool = False) -> list[dict]:
    sizes = _sizes(quick)
    net = None if quick else _torch_net()
    if net is not None:
        model, variables = from_torch(net.state_dict(), "espnet-cityscapes")
    else:
        model = ESPNet()
        variables = model.init(jax.random.key(0), jnp.zeros((1, 64, 64, 3)), train=False)
    weights = "authors' Cityscapes weights" if net is not None and CHECKPOINT.is_file() else "random weights"
    rows = []
    for shape in sizes["shapes"]:
        case = f"p2 q8 {shape[0]}x{shape[2]}x{shape[1]} float32"
        ms, rate = _jax_ms(model, variables, shape, sizes["repeats"])
        row = {"benchmark": "ESPNet forward", "case": case, "impl": "jaxanom", "median_ms": ms,
               "note": f"{1e3 * shape[0] / ms:.1f} images/s; {rate}; {weights}"}
        if net is not None:
            peer = _torch_ms(net, shape, sizes["repeats"])
            row["ratio"] = peer / ms
            rows += [row, {"benchmark": "ESPNet forward", "case": case, "impl": "pytorch", "median_ms": peer,
                           "note": f"{1e3 * shape[0] / peer:.1f} images/s"}]
        else:
            rows.append(row)
    return rows


if __name__ == "__main__":
    print(environment())
    print(markdown_table(run(quick="--quick" in sys.argv), ["benchmark", "case", "impl", "median_ms", "ratio", "note"]))
