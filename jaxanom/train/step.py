"""Pure train and eval steps, and their jitted, data-parallel forms.

The model contract (``jaxanom.models``): ``model.apply(variables, images, train=...)`` returns a
dict with ``"logits"`` (B, H, W, C) at input size, plus ``"attention"`` (B, h, w) for CuDAM or
``"branch_weights"`` (B, 3) for MSAAM; with ``train=True, mutable=["batch_stats"]`` it also
returns the updated BatchNorm statistics. A batch is ``{"image": (B, H, W, 3) uint8 RGB or float32 normalised,
"label": (B, H, W) int32}`` with 255 on void pixels. A model with further inputs names them in a
class attribute ``extra_inputs`` (e.g. MMF's RGBDNet: ``("depth",)``); the batch then carries
them under those names and they are passed to ``apply`` as keyword arguments.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import jax
import jax.numpy as jnp
import optax

from jaxanom import losses
from jaxanom._validate import check_count, check_number
from jaxanom.cudam_score import upsample_attention
from jaxanom.data.transforms import normalize
from jaxanom.metrics.segmentation import confusion_counts
from jaxanom.train.running_sml import running_sml_score, running_stats_update
from jaxanom.train.sharding import batch_sharding, replicated
from jaxanom.train.state import TrainState
from jaxanom.xla_options import conv_compiler_options, state_donation

METHODS = ("plain", "cudam", "msaam")
COMPUTE_DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}
ATTENTION_KS = ("msp", "running_sml")


@dataclasses.dataclass(frozen=True)
class LossConfig:
    """What a train step minimises; defaults are the papers' (CuDAM §IV; docs/papers/sml-cudam-msaam.md).

    ``method``: ``"plain"`` (cross-entropy), ``"cudam"`` (Eq. 8: reward Eq. 4 in study
    iterations + lambda (Eq. 9) * attention loss Eq. 7) or ``"msaam"`` (MSAAM Eq. 7;
    ``msaam_lambda`` is not given in the paper). ``compute_dtype="bfloat16"`` runs the forward
    pass with bfloat16 parameters and images; master weights, losses and updates stay float32.
    ``attention_k``: the k of L_att's weight e^k (Eq. 7): ``"msp"`` (1 - max softmax probability)
    or ``"running_sml"`` (SML from class statistics accumulated in the train state with EMA
    ``sml_decay``, ``jaxanom.train.running_sml``).
    """

    method: str = "plain"
    ignore: int = losses.IGNORE
    class_weights: tuple[float, ...] | None = None
    tau: float = 5e4
    reward_prob: float = 0.5
    beta: float = 0.5
    attention_literal: bool = False
    msaam_lambda: float = 0.1
    msaam_literal: bool = False
    compute_dtype: str = "float32"
    attention_k: str = "msp"
    sml_decay: float = 0.99

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method: expected one of {METHODS}, got {self.method!r}")
        if self.compute_dtype not in COMPUTE_DTYPES:
            raise ValueError(f"compute_dtype: expected one of {tuple(COMPUTE_DTYPES)}, got {self.compute_dtype!r}")
        if self.attention_k not in ATTENTION_KS:
            raise ValueError(f"attention_k: expected one of {ATTENTION_KS}, got {self.attention_k!r}")
        for name in ("tau", "beta", "msaam_lambda"):
            check_number(name, getattr(self, name), 0.0)
        for name in ("reward_prob", "sml_decay"):
            check_number(name, getattr(self, name), 0.0, 1.0)
        check_count("ignore", self.ignore, minimum=0)
        for index, weight in enumerate(self.class_weights or ()):
            check_number(f"class_weights[{index}]", weight, 0.0)
        if not 0.0 < self.sml_decay <= 1.0:
            raise ValueError(f"sml_decay: expected a decay in (0, 1], got {self.sml_decay}")
        if not 0.0 <= self.reward_prob <= 1.0:
            raise ValueError(f"reward_prob: expected a probability in [0, 1], got {self.reward_prob}")


def _cast(tree, dtype):
    return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def _forward(model, variables, images, cfg: LossConfig, **kwargs):
    dtype = COMPUTE_DTYPES[cfg.compute_dtype]
    variables = dict(variables, params=_cast(variables["params"], dtype))
    return model.apply(variables, model_input(images, model).astype(dtype), **kwargs)


def model_extras(model, batch: dict) -> dict:
    """The batch entries named by ``model.extra_inputs`` (none for the segmenters)."""
    return {name: batch[name] for name in getattr(model, "extra_inputs", ())}


def model_input(images, model=None) -> jax.Array:
    """Images as the model wants them: uint8 RGB batches are normalised here, on the device
    (4x fewer bytes to transfer than float32), with ``model.normalize_input`` where the network
    has its own (ESPNet's Cityscapes weights), else ImageNet's mean and std (``normalize``);
    float batches are taken as already normalised."""
    if images.dtype != jnp.uint8:
        return images
    return getattr(model, "normalize_input", normalize)(images)


def training_anomaly_score(logits) -> jax.Array:
    """k of the attention loss during training: 1 - max softmax probability of ``P_a``, (B, H, W).

    SML needs class statistics that do not exist while training, so CuDAM's ``e^k`` weight uses
    MSP here (bounded: e^k in [1, e)); stop-gradient.
    """
    return jax.lax.stop_gradient(1.0 - jnp.max(jax.nn.softmax(logits, axis=-1), axis=-1))


def objective(out: dict, labels, key, cfg: LossConfig, k=None) -> tuple[jax.Array, dict]:
    """The loss of one step from the model's outputs; ``(loss, aux metrics)``.

    CuDAM: ``L_seg`` on the (maybe) rewarded logits P; correctness for psi (Eq. 7) and lambda
    (Eq. 9) is judged on the model's own logits P_a, since with the reward nearly every pixel is
    "correct". ``k`` (B, H, W): L_att's anomaly score, by default ``training_anomaly_score``.
    """
    logits = out["logits"].astype(jnp.float32)
    if cfg.method == "plain":
        return losses.cross_entropy(logits, labels, cfg.ignore, cfg.class_weights), {}
    if cfg.method == "msaam":
        loss = losses.msaam_loss(logits, labels, out["branch_weights"], cfg.msaam_lambda,
                                 cfg.msaam_literal, cfg.ignore, cfg.class_weights)
        return loss, {}
    attention_up = upsample_attention(out["attention"], labels.shape[1:])
    rewarded, study = losses.study_logits(key, logits, attention_up, labels, cfg.tau, cfg.reward_prob, cfg.ignore)
    seg = losses.cross_entropy(rewarded, labels, cfg.ignore, cfg.class_weights)
    k = training_anomaly_score(logits) if k is None else k
    att = losses.attention_loss(attention_up, logits, labels, k, cfg.beta, cfg.attention_literal, cfg.ignore)
    lam = losses.self_regulated_lambda(logits, labels, cfg.ignore)
    return seg + lam * att, {"seg_loss": seg, "attention_loss": att, "lambda": lam, "study": study}


def train_step(state: TrainState, batch: dict, *, model, tx: optax.GradientTransformation,
               cfg: LossConfig) -> tuple[TrainState, dict]:
    """One optimisation step; returns the new state and float32 scalar metrics (``"loss"``, ...)."""
    study_key, dropout_key = jax.random.split(state.step_key())

    def loss_fn(params):
        variables = {"params": params, "batch_stats": state.batch_stats}
        out, updated = _forward(model, variables, batch["image"], cfg, train=True,
                                mutable=["batch_stats"], rngs={"dropout": dropout_key}, **model_extras(model, batch))
        sml_stats, k = state.sml_stats, None
        if cfg.method == "cudam" and cfg.attention_k == "running_sml":
            logits = out["logits"].astype(jnp.float32)
            sml_stats = running_stats_update(sml_stats, logits, batch["label"] != cfg.ignore, cfg.sml_decay)
            k = running_sml_score(sml_stats, logits)
        loss, aux = objective(out, batch["label"], study_key, cfg, k)
        return loss, (updated.get("batch_stats", {}), sml_stats, aux)

    (loss, (batch_stats, sml_stats, aux)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
    updates, opt_state = tx.update(grads, state.opt_state, state.params)
    new_state = state.replace(
        params=optax.apply_updates(state.params, updates),
        batch_stats=_cast(batch_stats, jnp.float32),
        opt_state=opt_state,
        step=state.step + 1,
        sml_stats=sml_stats,
    )
    metrics = {"loss": loss, "grad_norm": optax.tree.norm(grads), **aux}
    return new_state, jax.tree.map(lambda x: x.astype(jnp.float32), metrics)


def eval_step(variables: dict, batch: dict, *, model, cfg: LossConfig) -> jax.Array:
    """Confusion matrix (C, C) of one batch, no reward, BatchNorm in inference mode."""
    out = _forward(model, variables, batch["image"], cfg, train=False, **model_extras(model, batch))
    logits = out["logits"]
    return confusion_counts(jnp.argmax(logits, axis=-1), batch["label"], logits.shape[-1], cfg.ignore)


def _platform(mesh: jax.sharding.Mesh) -> str:
    return mesh.devices.flat[0].platform


def _options(mesh: jax.sharding.Mesh) -> dict[str, str]:
    """The convolution compiler options for the platform of ``mesh``'s devices."""
    return conv_compiler_options(_platform(mesh))


def jit_train_step(fn: Callable, mesh: jax.sharding.Mesh) -> Callable:
    """``fn(state, batch)`` jitted: state replicated (and donated, except on the CPU:
    ``xla_options.state_donation``), batch split along "data"."""
    rep = replicated(mesh)
    return jax.jit(fn, in_shardings=(rep, batch_sharding(mesh)), out_shardings=(rep, rep),
                   donate_argnums=state_donation(_platform(mesh)), compiler_options=_options(mesh))


def make_steps(model, tx, cfg: LossConfig, mesh: jax.sharding.Mesh) -> tuple[Callable, Callable]:
    """``(train_step(state, batch), eval_step(variables, batch))``, each jitted once for ``mesh``."""
    train = jit_train_step(functools.partial(train_step, model=model, tx=tx, cfg=cfg), mesh)
    rep = replicated(mesh)
    evaluate = jax.jit(functools.partial(eval_step, model=model, cfg=cfg),
                       in_shardings=(rep, batch_sharding(mesh)), out_shardings=rep,
                       compiler_options=_options(mesh))
    return train, evaluate
