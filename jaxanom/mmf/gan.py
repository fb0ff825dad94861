"""The SPADE synthesizer's losses (docs/papers/mmf.md#spade-generator; hinge GAN of [34], feature matching of pix2pixHD).

Discriminator outputs are lists over scales k = 1..K (``MultiscaleDiscriminator``)::

    hinge_discriminator_loss = 1/K sum_k [mean relu(1 - D_k(real)) + mean relu(1 + D_k(fake))]
    hinge_generator_loss     = 1/K sum_k  -mean D_k(fake)
    feature_matching_loss    = mean over scales k and layers l of mean |F_kl(real) - F_kl(fake)|
    l1_loss                  = mean |r - x|

``means`` run over every element. The real features are not differentiated (stop_gradient);
``generator_loss`` weights them as docs/papers/mmf.md#spade-generator says: hinge + 10 feature matching + 10 L1.
"""
from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp

FEATURE_WEIGHT = 10.0
L1_WEIGHT = 10.0


def hinge_discriminator_loss(real: Sequence[jax.Array], fake: Sequence[jax.Array]) -> jax.Array:
    """The critic's hinge loss over scales (lists of logits of any shape) -> scalar."""
    terms = [jnp.mean(jax.nn.relu(1 - r)) + jnp.mean(jax.nn.relu(1 + f)) for r, f in zip(real, fake, strict=True)]
    return sum(terms) / len(terms)


def hinge_generator_loss(fake: Sequence[jax.Array]) -> jax.Array:
    """The generator's hinge loss, -mean D(fake) averaged over scales -> scalar."""
    return sum(-jnp.mean(f) for f in fake) / len(fake)


def feature_matching_loss(real: Sequence[Sequence[jax.Array]], fake: Sequence[Sequence[jax.Array]]) -> jax.Array:
    """Mean L1 between real and fake critic features, over every layer of every scale -> scalar."""
    terms = [jnp.mean(jnp.abs(jax.lax.stop_gradient(r) - f))
             for rs, fs in zip(real, fake, strict=True) for r, f in zip(rs, fs, strict=True)]
    return sum(terms) / len(terms)


def l1_loss(generated: jax.Array, target: jax.Array) -> jax.Array:
    """``mean |generated - target|`` -> scalar (replaces [34]'s VGG loss)."""
    return jnp.mean(jnp.abs(generated - target))


def generator_loss(fake_logits, real_features, fake_features, generated, target,
                   feature_weight: float = FEATURE_WEIGHT, l1_weight: float = L1_WEIGHT) -> tuple[jax.Array, dict]:
    """hinge + feature_weight * FM + l1_weight * L1 -> (loss, {"g_hinge", "feature_matching", "l1"})."""
    parts = {"g_hinge": hinge_generator_loss(fake_logits),
             "feature_matching": feature_matching_loss(real_features, fake_features),
             "l1": l1_loss(generated, target)}
    return parts["g_hinge"] + feature_weight * parts["feature_matching"] + l1_weight * parts["l1"], parts
