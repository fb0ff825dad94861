"""ESPNet (p=2, q=8, light decoder) forward pass at 1024x512, batch 1 and 8, against PyTorch.

Both carry the same weights (the authors' Cityscapes checkpoint when the real-data folder
(``JAXANOM_REALDATA``) has it, else the peer's random ones), imported with ``jaxanom.weights.from_torch``; the comparison is
``benchmarks.forward_vs_torch``'s. ``quick`` runs 64x128 without the peer: a smoke test of the
code path.

    PYTHONPATH=. python benchmarks/bench_espnet.py [--quick]
"""
from __future__ import annotations

import sys

import jax
import jax.numpy as jnp

from benchmarks.forward_vs_torch import REALDATA, torch_reference, wall_rows
from benchmarks.timing import environment, markdown_table
from jaxanom.models import ESPNet
from jaxanom.weights import from_torch

CHECKPOINT = REALDATA / "espnet" / "espnet_p_2_q_8.pth"


def _sizes(quick: bool) -> dict:
    if quick:
        return {"shapes": [(1, 64, 128)], "repeats": 3}
    return {"shapes": [(1, 512, 1024), (8, 512, 1024)], "repeats": 10 if jax.default_backend() == "gpu" else 3}


def _torch_net():
    """The peer with the authors' weights (or random ones); None without torch."""
    reference = torch_reference()
    if reference is None:
        return None
    import torch

    net = reference.ESPNetTorch(classes=20, p=2, q=8)
    if CHECKPOINT.is_file():
        net.load_state_dict(torch.load(CHECKPOINT, map_location="cpu", weights_only=True))
    return net.eval()


def run(quick: bool = False) -> list[dict]:
    sizes = _sizes(quick)
    net = None if quick else _torch_net()
    if net is not None:
        model, variables = from_torch(net.state_dict(), "espnet-cityscapes")
    else:
        model = ESPNet()
        variables = model.init(jax.random.key(0), jnp.zeros((1, 64, 64, 3)), train=False)
    weights = "authors' Cityscapes weights" if net is not None and CHECKPOINT.is_file() else "random weights"
    return wall_rows("ESPNet forward", "p2 q8", model, variables, net, sizes["shapes"], sizes["repeats"], weights)


if __name__ == "__main__":
    print(environment())
    print(markdown_table(run(quick="--quick" in sys.argv), ["benchmark", "case", "impl", "median_ms", "ratio", "note"]))
