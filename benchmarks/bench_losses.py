"""CuDAM's training objective (Eqs. 4, 7-9) and plain cross-entropy: loss + gradient, jaxanom vs PyTorch.

What a CuDAM train step adds on top of the network: upsample the attention map to label size,
inject the reward (a "study" iteration, the costlier branch), cross-entropy with ignore, the
attention loss with its psi threshold and e^k weights, and lambda; then the gradient with
respect to the logits and the attention map. The peer is the same objective written below in
plain PyTorch (NCHW, ``F.interpolate``, ``F.cross_entropy(ignore_index=255)``), measured in the
same run; both compute float32 and their losses are compared (``note``). ``ratio`` = peer ms /
jaxanom ms (above 1: jaxanom is faster).

Sizes: Cityscapes-like 2 x 512 x 1024 labels, 19 classes, attention at output stride 8
(64 x 128); ``quick``: 1 x 128 x 256.

    PYTHONPATH=. python benchmarks/bench_losses.py [--quick]
"""
from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.timing import environment, markdown_table, median_ms, torch_device
from jaxanom import losses
from jaxanom.cudam.objective import CuDAM

NUM_CLASSES, TAU, BETA = 19, 5e4, 0.5


def _inputs(batch, height, width, stride=8, seed=0):
    rng = np.random.default_rng(seed)
    logits = rng.normal(size=(batch, height, width, NUM_CLASSES)).astype(np.float32) * 3
    labels = rng.integers(0, NUM_CLASSES, size=(batch, height, width)).astype(np.int32)
    labels[rng.random(labels.shape) < 0.1] = 255
    z = rng.normal(size=(batch, (height // stride) * (width // stride)))
    attention = (np.exp(z) / np.exp(z).sum(1, keepdims=True)).reshape(batch, height // stride, width // stride)
    return logits, labels, attention.astype(np.float32)


def _torch_objective(torch, logits, attention, labels, cudam: bool):
    """The same objective in PyTorch: logits (B, C, H, W), attention (B, h, w), labels (B, H, W)."""
    F = torch.nn.functional
    if not cudam:
        return F.cross_entropy(logits, labels, ignore_index=255)
    up = F.interpolate(attention[:, None], size=labels.shape[1:], mode="bilinear", align_corners=False)[:, 0]
    valid = labels != 255
    onehot = F.one_hot(torch.where(valid, labels, 0), NUM_CLASSES).permute(0, 3, 1, 2) * valid[:, None]
    seg = F.cross_entropy(logits + TAU * up[:, None] * onehot, labels, ignore_index=255)
    correct = valid & (logits.argmax(1) == labels)
    incorrect = valid & ~correct
    psi = (up * correct).sum((1, 2)) / correct.sum((1, 2)).clamp(min=1)
    threshold = (BETA * psi).detach()[:, None, None]
    weight = torch.exp(1 - torch.softmax(logits, 1).max(1).values).detach()
    penalised = incorrect & (up < threshold)
    att = torch.where(penalised, weight * (threshold - up), torch.zeros_like(up)).sum((1, 2)).mean()
    lam = correct.sum() / valid.sum().clamp(min=1)
    return seg + lam * att


def _jax_fn(cudam: bool):
    objective = CuDAM(tau=TAU, reward_prob=1.0)
    key = jax.random.key(0)

    def loss(logits, attention, labels):
        if not cudam:
            return losses.cross_entropy(logits, labels)
        return objective.loss({"logits": logits, "attention": attention}, {"label": labels}, key, None, 255)[0]

    return jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))


def run(quick: bool = False) -> list[dict]:
    import torch

    shape = (1, 128, 256) if quick else (2, 512, 1024)
    logits, labels, attention = _inputs(*shape)
    repeats = 3 if quick else 7
    rows = []
    for cudam in (False, True):
        fn = _jax_fn(cudam)
        args = (jnp.asarray(logits), jnp.asarray(attention), jnp.asarray(labels))
        jax_ms = median_ms(lambda: fn(*args), repeats=repeats)
        jax_loss = float(fn(*args)[0])

        device = torch_device()
        t_logits = torch.tensor(logits, device=device).permute(0, 3, 1, 2).contiguous().requires_grad_()
        t_attention = torch.tensor(attention, device=device).requires_grad_()
        t_labels = torch.tensor(labels, device=device).long()

        def torch_step():
            t_logits.grad = t_attention.grad = None
            value = _torch_objective(torch, t_logits, t_attention, t_labels, cudam)
            value.backward()
            return value.detach()

        torch_ms = median_ms(torch_step, repeats=repeats)
        torch_loss = float(torch_step())
        rows.append({"benchmark": "loss+grad", "case": f"{'cudam' if cudam else 'cross-entropy'} {shape}",
                     "impl": "jaxanom (jit)", "median_ms": jax_ms, "ratio": torch_ms / jax_ms,
                     "note": f"loss {jax_loss:.6g} vs torch {torch_loss:.6g}"})
        rows.append({"benchmark": "loss+grad", "case": f"{'cudam' if cudam else 'cross-entropy'} {shape}",
                     "impl": f"pytorch {device} (eager)", "median_ms": torch_ms, "ratio": 1.0, "note": ""})
    return rows


if __name__ == "__main__":
    print(environment())
    print(markdown_table(run(quick="--quick" in sys.argv)))
