"""DeepLabV3+ ResNet-101 (output stride 8): forward time with and without CuDAM, and training speed.

Rows: forward ms of the plain network and of the CuDAM network, CuDAM's overhead in percent,
and a training step (SGD with momentum, cross-entropy) in images/s. The peer is the same network
written as a plain PyTorch model below (torchvision is not installed here and its DeepLabV3 has
no V3+ decoder), CuDAM in the paper's order (resize, concatenate, 1x1 conv), measured in the
same run; ``ratio`` = peer ms / jaxanom ms (above 1: jaxanom is faster).

Sizes: the target's 1x1024x2048 forward and 8x768x768 training step in bfloat16 (PyTorch:
autocast bfloat16, channels-last) when a GPU is present; on a CPU small inputs in float32 (CPU
bfloat16 is emulated in both libraries, so its timings say nothing). ``quick`` runs the tiny
preset without the peer: a smoke test of the code paths, not a measurement of ResNet-101.
Parameters are filled on the host from ``jax.eval_shape`` shapes: ``init`` is not timed.
Both jaxanom steps are jitted with ``conv_compiler_options()`` and the train step donates its
state only off the CPU (``state_donation``), as the library's trainer's steps
(docs/decisions/cpu-speed.md; one thread each, CPU time: ``cpu_models_one_thread.py``).

    PYTHONPATH=. python benchmarks/bench_models.py [--quick]
"""
from __future__ import annotations

import math
import sys

import jax
import jax.numpy as jnp
import numpy as np
import optax

from benchmarks.timing import environment, flop_rate, markdown_table, median_ms
from jaxanom.models import build_model
from jaxanom.xla_options import conv_compiler_options, state_donation

NUM_CLASSES = 19


def _sizes(quick: bool) -> dict:
    gpu = jax.devices()[0].platform == "gpu"
    if quick:  # a smoke run of the code paths: compiling ResNet-101's training step alone
        # takes about a minute on 2 CPU cores
        return {"model": "deeplabv3plus_tiny", "forward": (1, 64, 128), "train": (2, 64, 64),
                "dtype": "float32", "repeats": 3}
    if gpu:
        return {"model": "deeplabv3plus_r101", "forward": (1, 1024, 2048), "train": (8, 768, 768),
                "dtype": "bfloat16", "repeats": 20}
    return {"model": "deeplabv3plus_r101", "forward": (1, 64, 128), "train": (2, 64, 64),
            "dtype": "float32", "repeats": 3}


def _host_variables(model, image_shape):
    """Random variables of ``model`` made on the host, shaped by ``jax.eval_shape``."""
    rng = np.random.default_rng(0)
    shapes = jax.eval_shape(
        lambda x: model.init(jax.random.key(0), x, train=False),
        jax.ShapeDtypeStruct((1, *image_shape[1:], 3), jnp.float32),
    )

    def fill(path, leaf):
        name = path[-1].key
        if name == "kernel":
            fan_in = math.prod(leaf.shape[:-1])
            return jnp.asarray(rng.normal(size=leaf.shape).astype(np.float32) / np.sqrt(fan_in))
        if name in ("scale", "var"):
            return jnp.ones(leaf.shape, jnp.float32)
        if name == "alpha":
            return jnp.full(leaf.shape, 0.1, jnp.float32)  # non-zero: the module contributes
        return jnp.zeros(leaf.shape, jnp.float32)

    return jax.tree_util.tree_map_with_path(fill, shapes)


def _jax_forward_ms(name, attention, shape, dtype, repeats):
    model = build_model(name, NUM_CLASSES, attention=attention, dtype=jnp.dtype(dtype))
    variables = _host_variables(model, shape)
    images = jnp.asarray(np.random.default_rng(1).normal(size=(*shape, 3)).astype(np.float32))
    forward = jax.jit(lambda v, x: model.apply(v, x, train=False)["logits"],
                      compiler_options=conv_compiler_options())
    ms = median_ms(lambda: forward(variables, images), repeats=repeats, warmup=2)
    return ms, flop_rate(forward, variables, images, ms=ms)


def jitted_train_step(model, tx):
    """One jitted optimizer step of ``model``: ``(params, batch_stats, opt_state, images, labels)`` ->
    ``(params, batch_stats, opt_state, loss)``, the state donated where the trainer donates it."""
    def step(params, batch_stats, opt_state, images, labels):
        def loss_fn(p):
            out, state = model.apply({"params": p, "batch_stats": batch_stats}, images, train=True,
                                     mutable=["batch_stats"])
            loss = optax.softmax_cross_entropy_with_integer_labels(out["logits"], labels).mean()
            return loss, state["batch_stats"]

        (loss, batch_stats), grads = jax.value_and_grad(loss_fn, has_aux=True)(params)
        updates, opt_state = tx.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), batch_stats, opt_state, loss

    return jax.jit(step, donate_argnums=(0, 1, 2) if state_donation() else (), compiler_options=conv_compiler_options())


def train_step_run(name: str, shape: tuple, dtype: str = "float32"):
    """``(run, jitted step, (state, images, labels))`` for ``name`` with CuDAM on random ``shape``
    ``(B, H, W)`` frames: one call of ``run`` is one SGD step (it updates ``state`` in place)."""
    model = build_model(name, NUM_CLASSES, attention="cudam", dtype=jnp.dtype(dtype))
    variables = _host_variables(model, shape)
    tx = optax.sgd(0.01, momentum=0.9)
    rng = np.random.default_rng(1)
    images = jnp.asarray(rng.normal(size=(*shape, 3)).astype(np.float32))
    labels = jnp.asarray(rng.integers(0, NUM_CLASSES, shape).astype(np.int32))

    step = jitted_train_step(model, tx)
    state = [variables["params"], variables["batch_stats"], tx.init(variables["params"])]

    def run():
        *state[:], loss = step(*state, images, labels)
        return jax.block_until_ready(loss)

    return run, step, (state, images, labels)


def _jax_train_ms(name, shape, dtype, repeats):
    run, step, (state, images, labels) = train_step_run(name, shape, dtype)
    ms = median_ms(run, repeats=repeats, warmup=2)
    return ms, flop_rate(step, *state, images, labels, ms=ms)


# ----------------------------------------------------------------------------- PyTorch peer
def _torch_deeplab(attention: str | None):
    """DeepLabV3+ ResNet-101, output stride 8, optional CuDAM (deep position), in plain PyTorch."""
    import torch
    import torch.nn.functional as F
    from torch import nn

    def cbr(cin, cout, k, stride=1, dilation=1, relu=True):
        layers = [nn.Conv2d(cin, cout, k, stride, dilation * (k - 1) // 2, dilation, bias=False),
                  nn.BatchNorm2d(cout)]
        return nn.Sequential(*layers, nn.ReLU(inplace=True)) if relu else nn.Sequential(*layers)

    class Bottleneck(nn.Module):
        def __init__(self, cin, width, stride, dilation):
            super().__init__()
            self.body = nn.Sequential(cbr(cin, width, 1), cbr(width, width, 3, stride, dilation),
                                      cbr(width, 4 * width, 1, relu=False))
            self.short = (cbr(cin, 4 * width, 1, stride, relu=False)
                          if stride != 1 or cin != 4 * width else nn.Identity())

        def forward(self, x):
            return torch.relu(self.body(x) + self.short(x))

    class CuDAM(nn.Module):
        def __init__(self, c_low, c_mid, c):
            super().__init__()
            self.att = nn.Conv2d(2, 1, 7, padding=3)
            self.fuse = nn.Conv2d(c_low + c_mid + c, c, 1)
            self.alpha = nn.Parameter(torch.tensor(0.1))

        def forward(self, fa, flow, fmid):
            size = fa.shape[-2:]
            s = self.att(torch.cat([fa.mean(1, keepdim=True), fa.amax(1, keepdim=True)], 1))
            m = torch.softmax(s.float().flatten(1), -1).view_as(s)
            up = lambda t: F.interpolate(t, size, mode="bilinear", align_corners=False)  # noqa: E731
            fsc = self.fuse(torch.cat([up(flow), up(fmid), fa], 1))
            return self.alpha * m.to(fa.dtype) * (fa + fsc) + fa

    class DeepLab(nn.Module):
        def __init__(self):
            super().__init__()
            self.stem = nn.Sequential(cbr(3, 64, 7, 2), nn.MaxPool2d(3, 2, 1))
            stages, cin = [], 64
            for width, blocks, stride, dilation in zip((64, 128, 256, 512), (3, 4, 23, 3),
                                                       (1, 2, 1, 1), (1, 1, 2, 4)):
                layers = []
                for j in range(blocks):
                    layers.append(Bottleneck(cin, width, stride if j == 0 else 1, dilation))
                    cin = 4 * width
                stages.append(nn.Sequential(*layers))
            self.stages = nn.ModuleList(stages)
            self.aspp = nn.ModuleList([cbr(2048, 256, 1)] + [cbr(2048, 256, 3, dilation=r) for r in (12, 24, 36)])
            self.pool = cbr(2048, 256, 1)
            self.project = cbr(5 * 256, 256, 1)
            self.low = cbr(256, 48, 1)
            self.dec0, self.dec1 = cbr(304, 256, 3), cbr(256, 256, 3)
            self.cudam = CuDAM(256, 512, 256) if attention == "cudam" else None
            self.classifier = nn.Conv2d(256, NUM_CLASSES, 1)

        def forward(self, x):
            size = x.shape[-2:]
            feats = [self.stem(x)]
            for stage in self.stages:
                feats.append(stage(feats[-1]))
            _, l1, l2, _, l4 = feats
            pooled = self.pool(l4.mean((2, 3), keepdim=True)).expand(-1, -1, *l4.shape[-2:])
            a = self.project(torch.cat([b(l4) for b in self.aspp] + [pooled], 1))
            a = F.interpolate(a, l1.shape[-2:], mode="bilinear", align_corners=False)
            y = self.dec0(torch.cat([a, self.low(l1)], 1))
            if self.cudam is not None:
                y = self.cudam(y, l1, l2)
            y = self.classifier(self.dec1(y))
            return F.interpolate(y, size, mode="bilinear", align_corners=False)

    return DeepLab()


def _torch_rows(sizes):
    """Forward ms (plain, CuDAM) and train-step ms of the PyTorch peer; None when torch is absent."""
    try:
        import torch
    except ImportError:
        return None
    device = "cuda" if torch.cuda.is_available() else "cpu"
    bf16 = sizes["dtype"] == "bfloat16"
    autocast = lambda: torch.autocast(device, torch.bfloat16, enabled=bf16)  # noqa: E731
    fmt = torch.channels_last if device == "cuda" else torch.contiguous_format
    results = {}
    for attention in (None, "cudam"):
        net = _torch_deeplab(attention).to(device, memory_format=fmt).eval()
        x = torch.randn(sizes["forward"][0], 3, *sizes["forward"][1:], device=device).to(memory_format=fmt)

        def forward():
            with torch.no_grad(), autocast():
                return net(x)

        results[attention] = median_ms(forward, repeats=sizes["repeats"], warmup=2)
    net = _torch_deeplab("cudam").to(device, memory_format=fmt).train()
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9)
    b, h, w = sizes["train"]
    x = torch.randn(b, 3, h, w, device=device).to(memory_format=fmt)
    y = torch.randint(0, NUM_CLASSES, (b, h, w), device=device)

    def step():
        opt.zero_grad(set_to_none=True)
        with autocast():
            loss = torch.nn.functional.cross_entropy(net(x).float(), y)
        loss.backward()
        opt.step()
        return loss

    results["train"] = median_ms(step, repeats=sizes["repeats"], warmup=2)
    return results


def run(quick: bool = False) -> list[dict]:
    sizes = _sizes(quick)
    dtype, repeats = sizes["dtype"], sizes["repeats"]
    net = "tiny" if quick else "R101"
    fwd_case = f"{net} OS8 {'x'.join(map(str, sizes['forward']))} {dtype}"
    train_case = f"{net} OS8 + CuDAM {'x'.join(map(str, sizes['train']))} {dtype}"
    name = sizes["model"]
    plain, plain_rate = _jax_forward_ms(name, None, sizes["forward"], dtype, repeats)
    cudam, cudam_rate = _jax_forward_ms(name, "cudam", sizes["forward"], dtype, repeats)
    train, train_rate = _jax_train_ms(name, sizes["train"], dtype, repeats)
    peer = None if quick else _torch_rows(sizes)
    batch = sizes["train"][0]

    def row(benchmark, case, impl, ms, peer_ms, **extra):
        r = {"benchmark": benchmark, "case": case, "impl": impl, "median_ms": ms}
        if peer_ms is not None:
            r["ratio"] = peer_ms / ms
        return {**r, **extra}

    rows = [
        row("forward", fwd_case, "jaxanom", plain, peer and peer[None], note=plain_rate),
        row("forward + CuDAM", fwd_case, "jaxanom", cudam, peer and peer["cudam"],
            note=f"CuDAM overhead {100 * (cudam / plain - 1):.1f}%; {cudam_rate}"),
        row("train step", train_case, "jaxanom", train, peer and peer["train"],
            note=f"{1e3 * batch / train:.1f} images/s; {train_rate}"),
    ]
    if peer is not None:
        rows += [
            row("forward", fwd_case, "pytorch", peer[None], None),
            row("forward + CuDAM", fwd_case, "pytorch", peer["cudam"], None,
                note=f"CuDAM overhead {100 * (peer['cudam'] / peer[None] - 1):.1f}%"),
            row("train step", train_case, "pytorch", peer["train"], None,
                note=f"{1e3 * batch / peer['train']:.1f} images/s"),
        ]
    return rows


if __name__ == "__main__":
    print(environment())
    print(markdown_table(run(quick="--quick" in sys.argv),
                         ["benchmark", "case", "impl", "median_ms", "ratio", "note"]))
