"""MSAAM's training objective (MSAAM Eq. 7): cross-entropy -/+ lambda * variance of the branch weights."""
from __future__ import annotations

import dataclasses
from typing import ClassVar

from jaxanom import losses
from jaxanom._validate import check_number
from jaxanom.objectives import Objective, register


@register
@dataclasses.dataclass(frozen=True)
class MSAAM(Objective):
    """``losses.msaam_loss``; reads the network's ``"branch_weights"`` (B, 3).

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

    def loss(self, outputs, batch, key, state, ignore):
        loss = losses.msaam_loss(outputs["logits"], batch["label"], outputs["branch_weights"], self.lam,
                                 self.literal, ignore, self.class_weights)
        return loss, {}, state
