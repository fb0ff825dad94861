"""The void-channel score: the softmax probability of a network's void output.

The ESPNet and ERFNet authors' Cityscapes weights have 20 outputs, the 19 trainIds and a class
trained on Cityscapes' void pixels (ego vehicle, image borders, unlabelled objects). The
community's ERFNet evaluations report that output's probability as an anomaly score, the "void
classifier": ``p_void = exp(F_void) / sum_c exp(F_c)`` over every channel, void included.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_rank, check_real
from jaxanom.data.cityscapes_labels import NUM_CLASSES
from jaxanom.method_registry import Method, register

# A network with one output more than Cityscapes' 19 trainIds carries a void class there (the ESPNet
# and ERFNet authors' weights). The other methods read every channel, void included, as measured in
# docs/decisions/espnet.md; the void method reads the void channel's probability.
VOID_CHANNEL = NUM_CLASSES


@jax.jit
def _void_probability(logits, channel):
    return jnp.take(jax.nn.softmax(logits, axis=-1), channel, axis=-1)


def void_probability_batch(logits, channel: int) -> jax.Array:
    """``softmax(logits)[..., channel]``: logits (B, H, W, C), any float dtype (computed in
    float32) -> float32 (B, H, W) in [0, 1], higher = more anomalous. ``channel``: the void
    output's index, 0 <= channel < C."""
    check_rank("logits", logits, 4, "(B, H, W, C)")
    if not 0 <= int(channel) < np.shape(logits)[-1]:
        raise ValueError(f"void_channel: expected a channel of the logits' {np.shape(logits)[-1]}, got {channel}")
    check_real("logits", logits)
    check_finite("logits", logits)
    return _void_probability(jnp.asarray(logits, jnp.float32), int(channel))


def without_channel(logits, channel: int = VOID_CHANNEL):
    """``logits`` (..., C) -> (..., C - 1) without ``channel`` (default: the void output)."""
    logits = jnp.asarray(logits)
    return jnp.concatenate([logits[..., :channel], logits[..., channel + 1:]], axis=-1)


register(Method("void", frozenset({"logits", "void_channel"}),
                lambda inputs, options: void_probability_batch(inputs["logits"], inputs["void_channel"]),
                "softmax probability of a 20-output network's void channel (the 'void classifier')"))
