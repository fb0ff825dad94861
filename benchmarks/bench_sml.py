"""SML post-processing: standardise + boundary suppression + dilated smoothing.

jaxanom (``sml.sml_score_batch``, NHWC) against a PyTorch implementation of the same
algorithm written here after the original code (NCHW: ReplicationPad2d + ones 3x3 conv for
the masked average, a 7x7 dilated conv for the smoothing, max-pool morphology for the
boundaries, a diamond conv for the expansion, a Python loop over iterations). Both get the
same 19-class logits (each in its own layout, prepared outside the timing); the script checks
that the two score maps agree before timing. Rows give ratio = this row's time / jaxanom's
(above 1: jaxanom is faster).

    PYTHONPATH=. python benchmarks/bench_sml.py [--quick]
"""
from __future__ import annotations

import argparse
import functools

import numpy as np

from benchmarks.timing import environment, markdown_table, gb_per_s, median_ms, same_as_cpu, torch_device

NUM_CLASSES = 19


def make_logits(batch: int, height: int, width: int, seed: int = 0) -> np.ndarray:
    """Region-structured logits (B, H, W, C): blocky class layout plus pixel noise."""
    rng = np.random.default_rng(seed)
    cell = 32
    coarse = rng.normal(size=(batch, -(-height // cell), -(-width // cell), NUM_CLASSES)).astype(np.float32) * 4
    logits = np.repeat(np.repeat(coarse, cell, axis=1), cell, axis=2)[:, :height, :width]
    return logits + rng.normal(size=logits.shape).astype(np.float32)


class TorchSML:
    """Standardisation + the original BoundarySuppressionWithSmoothing, in PyTorch (NCHW).

    ``tuned=False`` uses the original code's operations (single-channel ``conv2d`` for the 3x3
    sums, the diamond expansion and the dilated 7x7 Gaussian). ``tuned=True`` computes the
    same values with the faster CPU idioms: ``avg_pool2d(divisor_override=1)`` sums, iterated
    cross max-pools for the diamond, and a separable Gaussian from shifted slices.
    """

    def __init__(self, mean, std, *, tuned, device="cpu", width=4, iterations=4, kernel_size=7, sigma=1.0,
                 dilation=6):
        import torch

        self.torch, self.tuned = torch, tuned
        self.mean, self.std = torch.as_tensor(mean, device=device), torch.as_tensor(std, device=device)
        self.width, self.iterations, self.dilation = width, iterations, dilation
        self.ones3 = torch.ones(1, 1, 3, 3, device=device)
        c = (kernel_size - 1) / 2
        g = np.exp(-((np.arange(kernel_size) - c) ** 2) / (2 * sigma**2))
        g /= g.sum()
        self.gauss_1d = [float(v) for v in g.astype(np.float32)]
        self.gauss_2d = torch.tensor(np.outer(g, g), dtype=torch.float32, device=device)[None, None]
        self.reach = dilation * (kernel_size // 2)
        self.diamonds = {}
        for r in range(1, width):
            yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
            self.diamonds[r] = torch.tensor((np.abs(yy) + np.abs(xx) <= r).astype(np.float32), device=device)[None, None]

    def dilate_cross(self, x):
        f = self.torch.nn.functional
        return self.torch.maximum(f.max_pool2d(x, (3, 1), 1, (1, 0)), f.max_pool2d(x, (1, 3), 1, (0, 1)))

    def boundaries(self, pred):
        label = pred.float()
        return (self.dilate_cross(label) != -self.torch.nn.functional.max_pool2d(-label, 3, 1, 1)).float()

    def expand(self, boundaries, r):
        if r == 0:
            return boundaries
        if self.tuned:
            for _ in range(r):
                boundaries = self.dilate_cross(boundaries)
            return boundaries
        return (self.torch.nn.functional.conv2d(boundaries, self.diamonds[r], padding=r) > 0).float()

    def sum3(self, x):
        f = self.torch.nn.functional
        x = f.pad(x, (1, 1, 1, 1), mode="replicate")
        return f.avg_pool2d(x, 3, 1, divisor_override=1) if self.tuned else f.conv2d(x, self.ones3)

    def smooth(self, x):
        f = self.torch.nn.functional
        x = f.pad(x, (self.reach,) * 4, mode="replicate")
        if not self.tuned:
            return f.conv2d(x, self.gauss_2d, dilation=self.dilation)
        h, w = x.shape[2] - 2 * self.reach, x.shape[3] - 2 * self.reach
        d = self.dilation
        x = sum(g * x[:, :, k * d : k * d + h, :] for k, g in enumerate(self.gauss_1d))
        return sum(g * x[:, :, :, k * d : k * d + w] for k, g in enumerate(self.gauss_1d))

    def __call__(self, logits_nchw):
        torch = self.torch
        with torch.no_grad():
            max_logit, pred = logits_nchw.max(1, keepdim=True)
            out = (max_logit - self.mean[pred]) / self.std[pred]
            boundaries = self.boundaries(pred)
            step = self.width // self.iterations
            for it in range(self.iterations):
                prev = out
                r = 0 if it == self.iterations - 1 else self.width - step * it - 1
                keep = 1.0 - self.expand(boundaries, r)
                total, count = self.sum3(out * keep), self.sum3(keep).long()
                avg = torch.where(count == 0, prev, total / count)
                out = torch.where(keep == 0, avg, prev)
            return -self.smooth(out)[:, 0]


def run(quick: bool = False) -> list[dict]:
    import torch

    height, width = (128, 256) if quick else (1024, 2048)
    batches = (1, 2) if quick else (1, 8)
    rng = np.random.default_rng(1)
    mean = rng.normal(size=NUM_CLASSES).astype(np.float32) + 5
    std = (0.5 + rng.random(NUM_CLASSES)).astype(np.float32)
    device = torch_device()
    peers = {f"torch {device} (original ops)": TorchSML(mean, std, tuned=False, device=device),
             f"torch {device} (tuned)": TorchSML(mean, std, tuned=True, device=device)}
    # PyTorch's default TF32 convolutions on a GPU put the original's Gaussian smoothing 4.9e-3 off
    # float32 (H100, 2026-11-26; 1.1e-5 without TF32): the peers compute in float32 as jaxanom does.
    tf32 = torch.backends.cudnn.allow_tf32
    torch.backends.cudnn.allow_tf32 = False
    try:
        return _rows(quick, height, width, batches, mean, std, peers, device)
    finally:
        torch.backends.cudnn.allow_tf32 = tf32


def _rows(quick, height, width, batches, mean, std, peers, device) -> list[dict]:
    """The timed rows of ``run``, per batch: jaxanom, then each peer checked against it."""
    import jax
    import torch

    from jaxanom import sml

    rows = []
    gpu = jax.default_backend() == "gpu"
    repeats = lambda batch: 5 if quick or gpu else (3 if batch == 1 else 2)  # noqa: E731
    for batch in batches:
        logits = make_logits(batch, height, width)
        logits_jax = jax.device_put(logits)
        logits_torch = torch.from_numpy(np.ascontiguousarray(logits.transpose(0, 3, 1, 2))).to(device)
        ours = lambda: sml.sml_score_batch(logits_jax, mean, std)  # noqa: E731
        reference = np.asarray(ours())
        cpu_check = same_as_cpu(functools.partial(sml.sml_score_batch, logits, mean, std), reference)
        del logits
        jax_ms = median_ms(ours, repeats=repeats(batch), warmup=1)
        case = f"{batch}x{height}x{width}x{NUM_CLASSES}"
        rows.append(dict(benchmark="sml_postprocess", case=case, impl="jaxanom", median_ms=jax_ms,
                         ms_per_frame=jax_ms / batch, ratio=1.0,
                         note=f"sml_score_batch (jit(vmap)); logits read at {gb_per_s(logits_jax.nbytes, jax_ms)}"
                              f"{cpu_check}"))
        for name, peer in peers.items():
            diff = float(np.max(np.abs(peer(logits_torch).cpu().numpy() - reference)))
            if diff > 1e-4:
                raise AssertionError(f"jaxanom and {name} disagree by {diff} at batch {batch}")
            torch_ms = median_ms(lambda: peer(logits_torch), repeats=repeats(batch), warmup=1)
            rows.append(dict(benchmark="sml_postprocess", case=case, impl=name, median_ms=torch_ms,
                             ms_per_frame=torch_ms / batch, ratio=torch_ms / jax_ms, note=f"max |diff| {diff:.1e}"))
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a 128x256 map instead of 1024x2048")
    args = parser.parse_args()
    print(environment())
    print(markdown_table(run(quick=args.quick)))
