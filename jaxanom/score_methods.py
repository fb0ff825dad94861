"""The scores of ``jaxanom.scores`` as registered methods: they read the logits only."""
from __future__ import annotations

from jaxanom import scores
from jaxanom.method_registry import Method, register


def _of_logits(batch_score):
    """A method's score function ``(inputs, options)`` applying ``batch_score`` to the logits."""
    return lambda inputs, options: batch_score(inputs["logits"])


for _name, _score, _description in (
        ("msp", scores.msp_batch, "1 - maximum softmax probability"),
        ("max_logit", scores.max_logit_batch, "negative maximum logit (SML's baseline)"),
        ("entropy", scores.entropy_batch, "softmax entropy in nats"),
        ("energy", scores.energy_batch, "free energy -logsumexp of the logits (Liu et al. 2020)"),
        ("softmax_distance", scores.softmax_distance_batch,
         "1 - p_(1) + p_(2), the gap of the two largest softmax values (MMF Eq. 2)")):
    register(Method(_name, frozenset({"logits"}), _of_logits(_score), _description))
