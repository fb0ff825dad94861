"""MSAAM's loss and training objective (MSAAM Eq. 7): cross-entropy -/+ lambda * variance of the branch weights.

The variance is the population variance of the three branch weights of one image (the text asks
for different weights "across scale, space and channel"), averaged over the batch
(docs/papers/sml-cudam-msaam.md).
"""
from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from jaxanom import losses
from jaxanom.losses import IGNORE
from jaxanom._validate import check_number
from jaxanom.objectives import Objective, legacy_class_weights, register


def msaam_loss(logits, labels, branch_weights, lam: float, literal: bool = False,
               ignore: int = IGNORE, class_weights=None) -> jax.Array:
    """MSAAM loss (Eq. 7): cross-entropy -/+ ``lam`` * variance of the branch weights; float32 scalar.

    ``branch_weights`` (B, 3) are (alpha_sc, alpha_sp, alpha_c) per image. The default subtracts
    the variance (the text wants high variance); ``literal=True`` adds it, as printed.
    """
    losses.check_pair(logits, labels)
    if branch_weights.ndim != 2 or branch_weights.shape[0] != logits.shape[0]:
        raise ValueError(f"branch_weights: expected shape ({logits.shape[0]}, n_branches), got {branch_weights.shape}")
    variance = jnp.mean(jnp.var(branch_weights.astype(jnp.float32), axis=1))
    sign = 1.0 if literal else -1.0
    return losses.cross_entropy(logits, labels, ignore, class_weights) + sign * lam * variance


@register
@dataclasses.dataclass(frozen=True)
class MSAAM(Objective):
    """``msaam_loss``; reads the network's ``"branch_weights"`` (B, 3).

    ``lam``: the variance's weight (the paper gives none); ``literal``: add the variance as
    printed instead of subtracting it (the text wants high variance); ``class_weights``: of the
    cross-entropy.
    """

    needs: ClassVar[tuple[str, ...]] = ("branch_weights",)

    lam: float = 0.1
    literal: bool = False
    class_weights: tuple[float, ...] | None = None
    name: str = dataclasses.field(default="msaam", init=False)

    def __post_init__(self):
        check_number("lam", self.lam, 0.0)
        losses.check_class_weights(self.class_weights)

    @classmethod
    def from_legacy_loss(cls, loss, own_terms):
        return cls(lam=loss.get("msaam_lambda", 0.1) if own_terms else 0.0, literal=loss.get("msaam_literal", False),
                   class_weights=legacy_class_weights(loss))

    def loss(self, outputs, batch, key, state, ignore):
        loss = msaam_loss(outputs["logits"], batch["label"], outputs["branch_weights"], self.lam,
                                 self.literal, ignore, self.class_weights)
        return loss, {}, state
