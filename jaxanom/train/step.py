"""Pure train and eval steps, and their jitted, data-parallel forms.

The model contract (``jaxanom.models``): ``model.apply(variables, images, train=...)`` returns a
dict with ``"logits"`` (B, H, W, C) at input size, plus whatever named outputs the objective
reads (``jaxanom.objectives``); with ``train=True, mutable=["batch_stats"]`` it also returns the
updated BatchNorm statistics. A batch is ``{"image": (B, H, W, 3) uint8 RGB or float32 normalised,
"label": (B, H, W) int32}`` with ``ignore`` (255) on void pixels. A model with further inputs names
them in a class attribute ``extra_inputs`` (e.g. MMF's RGBDNet: ``("depth",)``); the batch then
carries them under those names and they are passed to ``apply`` as keyword arguments.

The step is handed the objective (what to minimise) and knows nothing of it but its contract.
``compute_dtype="bfloat16"`` runs the forward pass with bfloat16 parameters and images; master
weights, the logits handed to the objective, losses and updates stay float32.
"""
from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp
import optax

from jaxanom.data.transforms import normalize
from jaxanom.losses import IGNORE
from jaxanom.metrics.segmentation import confusion_counts
from jaxanom.objectives import Objective
from jaxanom.train.sharding import batch_sharding, replicated
from jaxanom.train.state import TrainState
from jaxanom.xla_options import conv_compiler_options, state_donation

COMPUTE_DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}


def _cast(tree, dtype):
    return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def _forward(model, variables, images, compute_dtype: str, **kwargs):
    dtype = COMPUTE_DTYPES[compute_dtype]
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


def check_outputs(objective: Objective, outputs, model=None) -> None:
    """ValueError unless ``outputs`` (the names of the model's outputs, or its output dict) hold
    ``"logits"`` and every output ``objective`` reads (``objective.needs``)."""
    missing = [name for name in ("logits", *objective.needs) if name not in outputs]
    if missing:
        network = type(model).__name__ if model is not None else "the model"
        raise ValueError(f"objective {objective.name!r} reads the model output(s) {missing}, which {network} does "
                         f"not produce (its outputs: {sorted(outputs)}); use a network that does or another objective")


def train_step(state: TrainState, batch: dict, *, model, tx: optax.GradientTransformation, objective: Objective,
               compute_dtype: str = "float32", ignore: int = IGNORE) -> tuple[TrainState, dict]:
    """One optimisation step of ``objective``; returns the new state and float32 scalar metrics
    (``"loss"``, ``"grad_norm"`` and the objective's own)."""
    loss_key, dropout_key = jax.random.split(state.step_key())

    def loss_fn(params):
        variables = {"params": params, "batch_stats": state.batch_stats}
        out, updated = _forward(model, variables, batch["image"], compute_dtype, train=True,
                                mutable=["batch_stats"], rngs={"dropout": dropout_key}, **model_extras(model, batch))
        check_outputs(objective, out, model)
        out = dict(out, logits=out["logits"].astype(jnp.float32))
        loss, aux, objective_state = objective.loss(out, batch, loss_key, state.objective_state, ignore)
        return loss, (updated.get("batch_stats", {}), objective_state, aux)

    (loss, (batch_stats, objective_state, aux)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
    updates, opt_state = tx.update(grads, state.opt_state, state.params)
    new_state = state.replace(
        params=optax.apply_updates(state.params, updates),
        batch_stats=_cast(batch_stats, jnp.float32),
        opt_state=opt_state,
        step=state.step + 1,
        objective_state=objective_state,
    )
    metrics = {"loss": loss, "grad_norm": optax.tree.norm(grads), **aux}
    return new_state, jax.tree.map(lambda x: x.astype(jnp.float32), metrics)


def eval_step(variables: dict, batch: dict, *, model, compute_dtype: str = "float32", ignore: int = IGNORE) -> jax.Array:
    """Confusion matrix (C, C) of one batch, BatchNorm in inference mode (no objective involved)."""
    out = _forward(model, variables, batch["image"], compute_dtype, train=False, **model_extras(model, batch))
    logits = out["logits"]
    return confusion_counts(jnp.argmax(logits, axis=-1), batch["label"], logits.shape[-1], ignore)


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


def make_steps(model, tx, objective: Objective, mesh: jax.sharding.Mesh, *, compute_dtype: str = "float32",
               ignore: int = IGNORE) -> tuple[Callable, Callable]:
    """``(train_step(state, batch), eval_step(variables, batch))``, each jitted once for ``mesh``."""
    if compute_dtype not in COMPUTE_DTYPES:
        raise ValueError(f"compute_dtype: expected one of {tuple(COMPUTE_DTYPES)}, got {compute_dtype!r}")
    train = jit_train_step(functools.partial(train_step, model=model, tx=tx, objective=objective,
                                             compute_dtype=compute_dtype, ignore=ignore), mesh)
    rep = replicated(mesh)
    evaluate = jax.jit(functools.partial(eval_step, model=model, compute_dtype=compute_dtype, ignore=ignore),
                       in_shardings=(rep, batch_sharding(mesh)), out_shardings=rep,
                       compiler_options=_options(mesh))
    return train, evaluate
