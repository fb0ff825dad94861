"""Training the patch encoder with InfoNCE on patch annotations (docs/papers/offroad.md#infonce), and embedding.

``AnnotatedFrames`` stacks frames with their patch annotations padded to ``A`` anchor slots.
``train_encoder`` runs Adam on Eq. 2: each step draws ``frames_per_step`` annotated frames,
builds every anchor's query / positive / negatives within its frame (``contrastive_batch``,
recomputed each step: no memory bank) and takes one optax update; the step is one jit compile
and the steps run on ``train.run_loop``.
``embed`` maps patches at given centres to unit embeddings, in fixed-size chunks (one compile).
"""
from __future__ import annotations

import dataclasses
from functools import lru_cache, partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxanom._validate import check_count, check_number
from jaxanom.models.alexnet import PatchAlexNet
from jaxanom.offroad.contrastive import info_nce
from jaxanom.offroad.pairs import contrastive_batch, gather_pairs
from jaxanom.offroad.patches import patches_batch
from jaxanom.train.run_loop import run_loop


@dataclasses.dataclass(frozen=True)
class EncoderConfig:
    """Patch side, context factor, encoder widths, InfoNCE and Adam settings (docs/papers/offroad.md#unstated-settings).

    Defaults are the paper-scale ones of docs/papers/offroad.md; ``tiny()`` is the CPU encoder. ``unit=False``
    leaves the last layer's output unnormalised (the supervised patch classifier's logits).
    """

    size: int = 32
    context: int = 2
    widths: tuple[int, int, int, int, int] = (64, 192, 384, 256, 256)
    hidden: int = 256
    dim: int = 16
    temperature: float = 0.1
    negatives: int = 16
    frames_per_step: int = 4
    steps: int = 5000
    lr: float = 1e-3
    unit: bool = True

    def __post_init__(self):
        for name in ("size", "context", "hidden", "dim", "negatives", "frames_per_step", "steps"):
            check_count(name, getattr(self, name))
        if len(self.widths) != 5:
            raise ValueError(f"widths: expected five layer widths (c1..c5), got {self.widths!r}")
        for index, width in enumerate(self.widths):
            check_count(f"widths[{index}]", width)
        check_number("temperature", self.temperature, 0.0, open_low=True)
        check_number("lr", self.lr, 0.0, open_low=True)
        if not isinstance(self.unit, bool):
            raise ValueError(f"unit: expected true or false, got {self.unit!r}")

    @classmethod
    def tiny(cls, **changes) -> "EncoderConfig":
        return cls(**{"widths": (16, 32, 64, 64, 64), "hidden": 64, "steps": 300, **changes})

    def model(self) -> PatchAlexNet:
        return PatchAlexNet(widths=self.widths, hidden=self.hidden, dim=self.dim, unit=self.unit)


class AnnotatedFrames(NamedTuple):
    """Frames and their patch annotations: images (F, H, W, 3) float32 in [0, 1]; centers
    (F, A, 2) int32; ids (F, A) int32 per-image label ids; valid (F, A) bool; reference (F, A)
    int32 hidden reference classes (-1 in padding; evaluation only)."""

    images: np.ndarray
    centers: np.ndarray
    ids: np.ndarray
    valid: np.ndarray
    reference: np.ndarray


def stack_annotations(images: list, annotations: list[dict], slots: int) -> AnnotatedFrames:
    """Stack uint8 frames and ``annotate`` results, padding each to ``slots`` anchors."""
    if not images or len(images) != len(annotations):
        raise ValueError(f"images, annotations: expected equal, non-zero lengths, got {len(images)}, {len(annotations)}")
    f = len(images)
    centers, ids = np.zeros((f, slots, 2), np.int32), np.zeros((f, slots), np.int32)
    valid, reference = np.zeros((f, slots), bool), np.full((f, slots), -1, np.int32)
    for i, ann in enumerate(annotations):
        n = len(ann["ids"])
        if n > slots:
            raise ValueError(f"annotations[{i}]: {n} patches exceed slots={slots}")
        centers[i, :n], ids[i, :n], valid[i, :n], reference[i, :n] = ann["centers"], ann["ids"], True, ann["reference"]
    if not valid.any():
        raise ValueError("annotations: no annotated patch in any frame (an empty annotation set)")
    stacked = np.stack([np.asarray(im, np.float32) / 255.0 for im in images])
    return AnnotatedFrames(stacked, centers, ids, valid, reference)


def concat_frames(a: AnnotatedFrames, b: AnnotatedFrames) -> AnnotatedFrames:
    """The frames of ``a`` then ``b`` (same image size and slots)."""
    return AnnotatedFrames(*(np.concatenate([x, y]) for x, y in zip(a, b)))


def init_encoder(key, config: EncoderConfig):
    """Encoder parameters for (size, size, 6) patches."""
    return _jitted_init(config.model())(key, jnp.zeros((1, config.size, config.size, 6)))["params"]


@lru_cache(maxsize=8)
def _jitted_init(model):
    """``model.init`` compiled once per (hashable) network; called eagerly it compiles every primitive."""
    return jax.jit(model.init)


def _optimizer(config: EncoderConfig) -> optax.GradientTransformation:
    return optax.adam(config.lr)


@partial(jax.jit, static_argnames=("config",), donate_argnums=(0, 1))
def _train_step(params, opt_state, key, data: AnnotatedFrames, config: EncoderConfig):
    k_frames, k_batch = jax.random.split(key)
    count = data.images.shape[0]
    chosen = jax.random.choice(k_frames, count, (config.frames_per_step,), replace=count < config.frames_per_step)
    pick = lambda x: x[chosen]  # noqa: E731
    batch = contrastive_batch(k_batch, pick(data.images), pick(data.centers), pick(data.ids), pick(data.valid),
                              size=config.size, negatives=config.negatives, context=config.context)
    f, a = batch["query"].shape[:2]

    def loss_fn(p):
        every = jnp.concatenate([batch["query"], batch["near"]]).reshape(-1, *batch["query"].shape[2:])
        z = config.model().apply({"params": p}, every)["embedding"].reshape(2, f, a, -1)
        z_q, z_pos, z_neg, mask = gather_pairs(z[0], z[1], batch)
        return info_nce(z_q, z_pos, z_neg, mask, config.temperature)

    loss, grads = jax.value_and_grad(loss_fn)(params)
    updates, opt_state = _optimizer(config).update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, loss


def train_encoder(key, params, data: AnnotatedFrames, config: EncoderConfig, *, steps: int | None = None,
                  progress: Callable | None = None) -> tuple[object, np.ndarray]:
    """``steps`` (default ``config.steps``) Adam updates on Eq. 2; returns ``(params, losses (steps,))``.

    ``progress(iterable)`` may wrap the step loop (e.g. tqdm).
    """
    steps = config.steps if steps is None else int(steps)
    if steps < 1:
        raise ValueError(f"steps: expected >= 1, got {steps}")
    params = jax.tree.map(jnp.array, params)  # a private copy: the step donates its buffers
    opt_state = _optimizer(config).init(params)
    device_data = AnnotatedFrames(*map(jnp.asarray, data))
    return run_updates(lambda params, opt_state, key: _train_step(params, opt_state, key, device_data, config),
                       params, opt_state, key, steps, progress)


def run_updates(update: Callable, params, opt_state, key, steps: int, progress: Callable | None) -> tuple[object, np.ndarray]:
    """``steps`` calls of ``update(params, opt_state, key) -> (params, opt_state, loss)`` with keys
    ``fold_in(key, 0 .. steps - 1)`` on ``train.run_loop``: ``(params, losses (steps,) float32)``.

    No checkpoints; the losses are read from the device once, at the end, and returned as they
    are (a non-finite one does not stop the run: the caller judges the curve).
    """
    def step(state, step_key):
        params, opt_state, loss = update(*state, step_key)
        return (params, opt_state), {"loss": loss}

    losses = []

    def keep_losses(logged: list, _) -> None:
        losses.extend(metrics["loss"] for _, metrics in logged)

    keys = (jax.random.fold_in(key, index) for index in range(steps))
    trained, _ = run_loop(step, lambda: (params, opt_state), keys, steps, on_log=keep_losses, finite=(),
                          progress=progress)
    return trained, np.asarray(losses, np.float32)


@partial(jax.jit, static_argnames=("config",))
def _embed_chunk(params, images, centers, config: EncoderConfig):
    x = patches_batch(images, centers, config.size, config.context)
    z = config.model().apply({"params": params}, x.reshape(-1, *x.shape[2:]))["embedding"]
    return z.reshape(*centers.shape[:2], -1)


def embed(params, images, centers, config: EncoderConfig, *, chunk: int = 8) -> np.ndarray:
    """Unit embeddings (F, P, D) (raw outputs when ``config.unit`` is False) of the patches at ``centers`` (F, P, 2) of ``images`` (F, H, W, 3) in [0, 1].

    Frames go through in chunks of ``chunk`` (the last padded), so any F compiles once.
    """
    images, centers = np.asarray(images, np.float32), np.asarray(centers, np.int32)
    if images.ndim != 4 or centers.ndim != 3 or centers.shape[0] != images.shape[0] or centers.shape[2] != 2:
        raise ValueError(f"images, centers: expected (F, H, W, 3) and (F, P, 2), got {images.shape}, {centers.shape}")
    out = []
    for start in range(0, len(images), chunk):
        im, ce = images[start:start + chunk], centers[start:start + chunk]
        pad = chunk - len(im)
        z = _embed_chunk(params, np.pad(im, ((0, pad), (0, 0), (0, 0), (0, 0))), np.pad(ce, ((0, pad), (0, 0), (0, 0))), config)
        out.append(np.asarray(z)[:len(im)])
    return np.concatenate(out)
