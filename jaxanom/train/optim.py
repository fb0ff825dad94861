"""The optimizer: SGD (momentum 0.9, weight decay 5e-4) or AdamW, poly learning rate with warm-up.

SGD follows the DeepLabV3+ Cityscapes recipe: L2 weight decay added to the gradient before
momentum (as PyTorch's ``SGD(weight_decay=...)``), applied only to weights with two or more
dimensions (convolution and dense kernels), never to biases, normalisation scales/offsets or
scalars such as an attention module's gate. AdamW (decoupled decay, same mask) is the other
optimizer the segmentation papers use.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import optax

from jaxanom._validate import check_count, check_number

OPTIMIZERS = ("sgd", "adamw")


@dataclasses.dataclass(frozen=True)
class OptimConfig:
    """Optimizer settings. ``lr`` is the peak learning rate, reached after ``warmup_steps``.

    The schedule counts optimizer updates: with ``accum_steps`` k > 1, gradients of k
    consecutive steps are averaged (``optax.MultiSteps``) and the parameters move every k steps.
    """

    name: str = "sgd"
    lr: float = 0.01
    momentum: float = 0.9
    weight_decay: float = 5e-4
    poly_power: float = 0.9
    warmup_steps: int = 0
    end_lr: float = 0.0
    clip_norm: float | None = None
    accum_steps: int = 1

    def __post_init__(self):
        if self.name not in OPTIMIZERS:
            raise ValueError(f"name: expected one of {OPTIMIZERS}, got {self.name!r}")
        check_number("lr", self.lr, 0.0, open_low=True)
        for name in ("momentum", "weight_decay", "poly_power", "end_lr"):
            check_number(name, getattr(self, name), 0.0)
        check_count("accum_steps", self.accum_steps)
        check_count("warmup_steps", self.warmup_steps, minimum=0)
        if self.clip_norm is not None:  # a NaN clip norm would scale every update to NaN
            check_number("clip_norm", self.clip_norm, 0.0, open_low=True)


def poly_schedule(config: OptimConfig, updates: int) -> optax.Schedule:
    """Linear warm-up from 0 to ``lr``, then ``lr * (1 - t / T) ** poly_power`` down to ``end_lr``."""
    decay_steps = updates - config.warmup_steps
    if decay_steps < 1:
        raise ValueError(f"steps: expected more optimizer updates than warmup_steps={config.warmup_steps}, got {updates}")
    poly = optax.polynomial_schedule(config.lr, config.end_lr, config.poly_power, decay_steps)
    if config.warmup_steps == 0:
        return poly
    warmup = optax.linear_schedule(0.0, config.lr, config.warmup_steps)
    return optax.join_schedules([warmup, poly], [config.warmup_steps])


def schedule_depends_on_steps(config: OptimConfig) -> bool:
    """Whether the learning rate at a step depends on the run's total steps: the poly decay ends at
    the last step unless it is flat (``poly_power`` 0 or ``end_lr`` equal to ``lr``)."""
    return config.poly_power > 0 and config.end_lr != config.lr


def decay_mask(params) -> object:
    """True for the leaves that get weight decay: arrays with ndim >= 2 (kernels)."""
    return jax.tree.map(lambda p: p.ndim >= 2, params)


def make_optimizer(config: OptimConfig, steps: int) -> tuple[optax.GradientTransformation, Callable]:
    """``(tx, lr_at_step)`` for a run of ``steps`` train steps.

    ``lr_at_step(step)`` is the learning rate used by the update of train step ``step``.
    """
    updates = steps // config.accum_steps
    schedule = poly_schedule(config, updates)
    if config.name == "sgd":
        core = optax.chain(
            optax.add_decayed_weights(config.weight_decay, mask=decay_mask),
            optax.sgd(schedule, momentum=config.momentum),
        )
    else:
        core = optax.adamw(schedule, weight_decay=config.weight_decay, mask=decay_mask)
    if config.clip_norm is not None:
        core = optax.chain(optax.clip_by_global_norm(config.clip_norm), core)
    if config.accum_steps > 1:
        core = optax.MultiSteps(core, every_k_schedule=config.accum_steps)
    return core, lambda step: schedule(step // config.accum_steps)
