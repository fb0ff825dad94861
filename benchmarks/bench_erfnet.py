"""ERFNet forward pass at 1024x512, batch 1 and 8, against PyTorch.

Both carry the same weights (the authors' Cityscapes weights, the int8 redistribution dequantised,
when the real-data folder (``JAXANOM_REALDATA``) has them, else the peer's random ones), imported with
``jaxanom.weights.from_torch``; the comparison is ``benchmarks.forward_vs_torch``'s. ``quick`` runs
64x128 without the peer: a smoke test of the code path. ``--one-thread`` (run as a script) gives
the robust comparison on a shared CPU: one thread each, interleaved, process CPU time.

    PYTHONPATH=. python benchmarks/bench_erfnet.py [--quick | --one-thread [--repeats N]]
"""
from __future__ import annotations

import os
import sys

if __name__ == "__main__" and "--one-thread" in sys.argv:  # before JAX starts: XLA reads its flags once
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from benchmarks.forward_vs_torch import REALDATA, cpu_rows, torch_reference, wall_rows  # noqa: E402
from benchmarks.timing import environment, markdown_table  # noqa: E402
from jaxanom.models import ERFNet  # noqa: E402
from jaxanom.weights import from_torch, read_state_dict  # noqa: E402

WEIGHTS = REALDATA / "erfnet" / "erfnet_cityscapes_int8.pth"
SHAPES = [(1, 512, 1024), (8, 512, 1024)]


def _peer():
    """``(net, state, weights)``: the peer (None without torch) and the state dict both sides load."""
    reference = torch_reference()
    if reference is None:
        return None, None, "random weights"
    import torch

    if WEIGHTS.is_file():  # the int8 file: bn1 folded into conv1x3_1, so the peer is the fused rendering
        state = read_state_dict(WEIGHTS)
        net = reference.ERFNetTorch(classes=20, fused=True)
        net.load_state_dict({k: torch.from_numpy(v) for k, v in state.items() if k in net.state_dict()}, strict=True)
        return net.eval(), state, "authors' Cityscapes weights (int8 file, dequantised)"
    net = reference.ERFNetTorch(classes=20).eval()
    return net, net.state_dict(), "random weights"


def _networks(quick: bool):
    net, state, weights = (None, None, "random weights") if quick else _peer()
    if state is not None:
        model, variables = from_torch(state, "erfnet-cityscapes")
    else:
        model = ERFNet()
        variables = model.init(jax.random.key(0), jnp.zeros((1, 64, 64, 3)), train=False)
    return model, variables, net, weights


def run(quick: bool = False) -> list[dict]:
    model, variables, net, weights = _networks(quick)
    shapes = [(1, 64, 128)] if quick else SHAPES
    repeats = 10 if jax.default_backend() == "gpu" else 3
    return wall_rows("ERFNet forward", "", model, variables, net, shapes, repeats, weights)


if __name__ == "__main__":
    print(environment())
    columns = ["benchmark", "case", "impl", "median_ms", "ratio", "note"]
    if "--one-thread" in sys.argv:
        repeats = int(sys.argv[sys.argv.index("--repeats") + 1]) if "--repeats" in sys.argv else 5
        model, variables, net, weights = _networks(quick=False)
        print(weights)
        for shape in SHAPES:  # a table per shape as it finishes (batch 8 takes minutes on one thread)
            print(markdown_table(cpu_rows("ERFNet forward", "", model, variables, net, [shape], repeats), columns),
                  flush=True)
    else:
        print(markdown_table(run(quick="--quick" in sys.argv), columns))
