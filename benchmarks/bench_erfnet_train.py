"""ERFNet's training step (batch 4, 352x480, float32: a CamVid crop, 11 classes) against PyTorch's.

jaxanom's step is the trainer's own (``jaxanom.train.step.make_steps``: cross-entropy, SGD with
momentum 0.9 and weight decay 5e-4 from ``OptimConfig()``, uint8 images scaled on the device); the
peer is ``tests/torch_reference.py``'s ERFNet in train mode with the authors' channel dropout (0.03
at 64 channels, 0.3 at 128, after each encoder block's second BN, as their code has it) and the
same loss and optimizer. Same weights on both sides: the authors' Cityscapes weights where the
real-data folder (``JAXANOM_REALDATA``) has the int8 file (each block's ``bn1`` the identity, as
jaxanom's import gives it), with a fresh 11-class output layer; else the peer's random ones.

``run(quick)`` (``python -m benchmarks``) gives median wall times; ``quick`` a 2x64x96 step.
As a script, ``--one-thread`` gives the robust comparison on a shared CPU: one thread each
(``torch.set_num_threads(1)``, ``--xla_cpu_multi_thread_eigen=false``), the two steps alternating
call by call in one process, median process CPU time; ``--size BxHxW`` picks another batch.

    PYTHONPATH=. python benchmarks/bench_erfnet_train.py [--quick | --one-thread [--repeats N] [--size BxHxW]]
"""
from __future__ import annotations

import os
import sys

if __name__ == "__main__" and "--one-thread" in sys.argv:  # before JAX starts: XLA reads its flags once
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()

import jax  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.forward_vs_torch import REALDATA, torch_reference  # noqa: E402
from benchmarks.timing import environment, markdown_table, median_ms  # noqa: E402

WEIGHTS = REALDATA / "erfnet" / "erfnet_cityscapes_int8.pth"
SHAPE, QUICK_SHAPE = (4, 352, 480), (2, 64, 96)
CLASSES = 11
ENCODER_DROPOUT = {range(1, 6): 0.03, range(7, 15): 0.3}  # the authors' rates by encoder layer index


def torch_network():
    """``(net, weights)``: the peer ERFNet (train mode, channel dropout) and which weights it holds."""
    import torch
    import torch.nn.functional as F

    net = torch_reference().ERFNetTorch(classes=CLASSES)
    weights = "random weights"
    if WEIGHTS.is_file():
        from jaxanom.weights import read_state_dict

        own = net.state_dict()
        state = {k: torch.from_numpy(v) for k, v in read_state_dict(WEIGHTS).items()
                 if k in own and own[k].shape == v.shape}
        net.load_state_dict(state, strict=False)  # bn1: the identity; the output layer: fresh
        weights = "authors' Cityscapes weights (int8 file, dequantised), fresh 11-class output layer"
    for layers, p in ENCODER_DROPOUT.items():
        for i in layers:
            net.encoder.layers[i].bn2.register_forward_hook(
                lambda module, inputs, output, p=p: F.dropout2d(output, p, module.training))
    return net.train(), weights


def jax_step(net, shape):
    """One call is one trainer step of jaxanom's ERFNet holding ``net``'s weights on ``shape`` batches."""
    from jaxanom.losses import CrossEntropy
    from jaxanom.train.optim import OptimConfig, make_optimizer
    from jaxanom.train.sharding import global_batch, make_mesh
    from jaxanom.train.state import TrainState
    from jaxanom.train.step import make_steps
    from jaxanom.weights import from_torch

    model, variables = from_torch({k: v.numpy() for k, v in net.state_dict().items()}, "erfnet-cityscapes")
    mesh = make_mesh(jax.devices()[:1])
    tx, _ = make_optimizer(OptimConfig(), 1000)
    train_step, _ = make_steps(model, tx, CrossEntropy(), mesh)
    batch = global_batch(_batch(shape), mesh)
    state = [jax.device_put(TrainState.create(variables, tx, jax.random.key(0)))]

    def run():
        with jax.set_mesh(mesh):
            state[0], metrics = train_step(state[0], batch)
        return jax.block_until_ready(metrics["loss"])

    run()  # compiled here, outside any timing
    return run


def torch_step(net, shape):
    """One call is one SGD step of the peer on the same batch as jaxanom's."""
    import torch

    optimizer = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4)
    batch = _batch(shape)
    images = torch.from_numpy(batch["image"]).permute(0, 3, 1, 2).float() / 255
    labels = torch.from_numpy(batch["label"]).long()

    def run():
        optimizer.zero_grad(set_to_none=True)
        loss = torch.nn.functional.cross_entropy(net(images), labels, ignore_index=255)
        loss.backward()
        optimizer.step()
        return loss

    return run


def _batch(shape):
    rng = np.random.default_rng(1)
    labels = rng.integers(0, CLASSES + 1, shape).astype(np.int32)
    return {"image": rng.integers(0, 256, (*shape, 3), dtype=np.uint8),
            "label": np.where(labels == CLASSES, 255, labels)}


def _case(shape) -> str:
    return f"{shape[0]}x{shape[1]}x{shape[2]} float32, {CLASSES} classes"


def run(quick: bool = False) -> list[dict]:
    """Median wall ms of each side's step (jaxanom's default threads; PyTorch's)."""
    shape = QUICK_SHAPE if quick else SHAPE
    net, weights = torch_network()
    repeats = 3 if quick else 5
    ours = median_ms(jax_step(net, shape), repeats=repeats, warmup=1)
    peer = median_ms(torch_step(net, shape), repeats=repeats, warmup=1)
    note = f"{1e3 * shape[0] / ours:.2f} images/s; {weights}"
    return [{"benchmark": "ERFNet train step", "case": _case(shape), "impl": "jaxanom", "median_ms": ours,
             "ratio": peer / ours, "note": note},
            {"benchmark": "ERFNet train step", "case": _case(shape), "impl": "pytorch", "median_ms": peer,
             "note": f"{1e3 * shape[0] / peer:.2f} images/s"}]


def one_thread(shape, repeats: int) -> list[dict]:
    """One thread each, interleaved: median process CPU ms of each side's step, with the load average."""
    import statistics

    import torch

    from benchmarks.cpu_models_one_thread import interleaved_cpu_ms

    torch.set_num_threads(1)
    net, weights = torch_network()
    load = os.getloadavg()[0]
    times = interleaved_cpu_ms({"jaxanom": jax_step(net, shape), "pytorch": torch_step(net, shape)}, repeats,
                               warmup=1)
    ms = {name: statistics.median(t) for name, t in times.items()}
    note = (f"one thread, CPU time, median of {repeats}; load average {load:.1f}-{os.getloadavg()[0]:.1f}; {weights}")
    return [{"benchmark": "ERFNet train step", "case": _case(shape), "impl": name, "median_ms": ms[name],
             **({"ratio": ms["pytorch"] / ms["jaxanom"], "note": note} if name == "jaxanom" else
                {"note": "CPU ms: " + " ".join(f"{v:.0f}" for v in times[name])})} for name in times]


if __name__ == "__main__":
    print(environment())
    columns = ["benchmark", "case", "impl", "median_ms", "ratio", "note"]
    if "--one-thread" in sys.argv:
        repeats = int(sys.argv[sys.argv.index("--repeats") + 1]) if "--repeats" in sys.argv else 5
        size = sys.argv[sys.argv.index("--size") + 1] if "--size" in sys.argv else "x".join(map(str, SHAPE))
        print(markdown_table(one_thread(tuple(int(v) for v in size.split("x")), repeats), columns))
    else:
        print(markdown_table(run(quick="--quick" in sys.argv), columns))
