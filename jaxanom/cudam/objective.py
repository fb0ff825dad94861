"""CuDAM's training objective (Eq. 8): cross-entropy on rewarded logits plus the attention loss.

``L = L_seg(P) + lambda * L_att``: in a "study" iteration (probability ``reward_prob``) P is the
network's logits P_a rewarded by ``tau * up(M_att)`` on the true class (Eq. 4), else P = P_a;
L_att (Eq. 7) pulls attention towards uncertain, wrongly predicted pixels, weighted by e^k with
k an anomaly score; lambda (Eq. 9) is the batch's share of correctly predicted valid pixels.
Correctness for psi and lambda is judged on P_a, since with the reward nearly every pixel is
"correct". The pieces are ``jaxanom.cudam.losses``' functions and ``jaxanom.losses.cross_entropy``;
decisions in docs/decisions/cudam.md.
"""
from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from jaxanom import losses
from jaxanom._validate import check_number
from jaxanom.cudam.losses import attention_loss, self_regulated_lambda, study_logits
from jaxanom.cudam.score import paper_tau, upsample_attention
from jaxanom.objectives import Objective, legacy_class_weights, register

ATTENTION_KS = ("msp", "running_sml")


def training_anomaly_score(logits) -> jax.Array:
    """k of the attention loss from the logits alone: 1 - max softmax probability of ``P_a``, (B, H, W).

    SML needs class statistics that do not exist while training; MSP needs none (bounded:
    e^k in [1, e)). Stop-gradient.
    """
    return jax.lax.stop_gradient(1.0 - jnp.max(jax.nn.softmax(logits, axis=-1), axis=-1))


@register
@dataclasses.dataclass(frozen=True)
class CuDAM(Objective):
    """CuDAM's loss (Eq. 8); reads the network's attention map ``"attention"`` (B, h, w).

    ``tau``: the reward weight of Eq. 4; None (default) is the paper's 5e4 rescaled to the
    attention map's h * w positions (``cudam.score.paper_tau``; the paper's maps have 180 x 180),
    resolved from the map's static shape when the step is traced. ``reward_prob``: probability
    of a study iteration; ``beta``: L_att's threshold factor; ``attention_literal``: Eq. 7 as
    printed (``cudam.losses.attention_loss``). ``attention_k``: L_att's k, ``"msp"``
    (``training_anomaly_score``) or ``"running_sml"`` (SML from class statistics of the
    network's own predictions, an EMA with ``sml_decay`` kept as this objective's state:
    ``jaxanom.sml.running``). ``class_weights``: of L_seg's cross-entropy. With
    ``reward_prob=0`` and ``beta=0`` (no study iteration, no penalised pixel) the loss is the
    plain cross-entropy, to the bit: the attention module trained by L_seg alone (CuDAM Table III).
    """

    needs: ClassVar[tuple[str, ...]] = ("attention",)

    tau: float | None = None
    reward_prob: float = 0.5
    beta: float = 0.5
    attention_literal: bool = False
    attention_k: str = "msp"
    sml_decay: float = 0.99
    class_weights: tuple[float, ...] | None = None
    name: str = dataclasses.field(default="cudam", init=False)

    def __post_init__(self):
        if self.tau is not None:
            check_number("tau", self.tau, 0.0)
        check_number("beta", self.beta, 0.0)
        check_number("reward_prob", self.reward_prob, 0.0, 1.0)
        check_number("sml_decay", self.sml_decay, 0.0, 1.0, open_low=True)
        if self.attention_k not in ATTENTION_KS:
            raise ValueError(f"attention_k: expected one of {ATTENTION_KS}, got {self.attention_k!r}")
        losses.check_class_weights(self.class_weights)

    def reward_weight(self, attention_positions: int) -> float:
        """The tau used on an attention map of ``attention_positions`` = h * w positions."""
        return paper_tau(attention_positions) if self.tau is None else float(self.tau)

    def describe(self, outputs):
        attention = outputs["attention"]
        return f"CuDAM tau = {self.reward_weight(attention.shape[-2] * attention.shape[-1]):.6g}"

    @classmethod
    def from_legacy_loss(cls, loss, own_terms):
        """A run whose k came from running SML statistics cannot be read: its checkpoints hold them
        under an earlier name."""
        if loss.get("attention_k", "msp") != "msp":
            raise ValueError("train.loss.attention_k: a run of an earlier jaxanom with attention_k="
                             f"{loss['attention_k']!r} keeps its statistics in checkpoints this version cannot "
                             "read; train it again")
        terms = {"reward_prob": loss.get("reward_prob", 0.5), "beta": loss.get("beta", 0.5)} if own_terms else \
            {"reward_prob": 0.0, "beta": 0.0}
        return cls(tau=loss.get("tau", 5e4), attention_literal=loss.get("attention_literal", False),
                   class_weights=legacy_class_weights(loss), **terms)

    def init_state(self, num_classes: int):
        """Empty running SML statistics (``sml.ClassStats``) with ``attention_k="running_sml"``, else None."""
        from jaxanom.sml.stats import stats_init

        return stats_init(num_classes) if self.attention_k == "running_sml" else None

    def loss(self, outputs, batch, key, state, ignore):
        from jaxanom.sml.running import running_sml_score, running_stats_update

        logits, labels, attention = outputs["logits"], batch["label"], outputs["attention"]
        if self.reward_prob == 0 and self.beta == 0:
            # L_seg alone, computed as the plain cross-entropy is: the full graph gives the same loss,
            # but XLA fuses it differently and the gradient may differ in the last bit
            return losses.cross_entropy(logits, labels, ignore, self.class_weights), {}, state
        k = None
        if self.attention_k == "running_sml":
            state = running_stats_update(state, logits, labels != ignore, self.sml_decay)
            k = running_sml_score(state, logits)
        tau = self.reward_weight(attention.shape[-2] * attention.shape[-1])
        attention_up = upsample_attention(attention, labels.shape[1:])
        rewarded, study = study_logits(key, logits, attention_up, labels, tau, self.reward_prob, ignore)
        seg = losses.cross_entropy(rewarded, labels, ignore, self.class_weights)
        k = training_anomaly_score(logits) if k is None else k
        att = attention_loss(attention_up, logits, labels, k, self.beta, self.attention_literal, ignore)
        lam = self_regulated_lambda(logits, labels, ignore)
        return seg + lam * att, {"seg_loss": seg, "attention_loss": att, "lambda": lam, "study": study}, state
