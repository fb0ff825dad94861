"""CuDAM's attention upsampling ``up(.)`` (Eqs. 4, 10) and its ensemble anomaly score (Eq. 10).

Attention values are about 1 / (h * w) (the map sums to 1 per image), hence the large sigma;
the arithmetic stays in float32.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp


def upsample_attention(attention, size: tuple[int, int]) -> jax.Array:
    """Bilinear upsampling of attention maps ``(..., h, w)`` to ``(..., H, W)``, float32.

    Half-pixel centres (PyTorch's ``align_corners=False``). Values are not renormalised: an
    upsampled map keeps the per-pixel magnitude ~1 / (h * w) that tau and sigma were tuned for.
    """
    attention = jnp.asarray(attention, jnp.float32)
    if attention.ndim < 2 or len(size) != 2:
        raise ValueError(f"attention: expected shape (..., h, w) and size (H, W), got {attention.shape} and {size}")
    return jax.image.resize(attention, attention.shape[:-2] + tuple(size), method="bilinear")


def cudam_score(anomaly_score, attention_up, sigma: float = 2e4) -> jax.Array:
    """CuDAM ensemble (Eq. 10): ``P_ano = K + sigma * up(M_att)``, float32, higher = more anomalous.

    ``anomaly_score`` K (any score: SML, MSP, max logit) and ``attention_up`` share one shape,
    ``(H, W)`` for an image or ``(B, H, W)`` for a batch (the sum is elementwise). ``sigma`` may
    be traced (``jax.jit`` / ``vmap`` over a grid of sigmas).
    """
    anomaly_score = jnp.asarray(anomaly_score, jnp.float32)
    attention_up = jnp.asarray(attention_up, jnp.float32)
    if anomaly_score.shape != attention_up.shape:
        raise ValueError(
            f"attention_up: expected the anomaly_score's shape {anomaly_score.shape} "
            f"(upsample with upsample_attention first), got {attention_up.shape}")
    return _ensemble(anomaly_score, attention_up, jnp.float32(sigma))


@jax.jit
def _ensemble(anomaly_score, attention_up, sigma):
    return anomaly_score + sigma * attention_up


# CuDAM's attention map is 180 x 180 on its 720 x 720 training crops (Table V's text: "insert
# location feature size is (304, 180, 180)") and 256 x 512 on 1024 x 2048 Cityscapes frames
# (stride 4), so tau and sigma were tuned for maps of these many positions.
PAPER_TRAIN_POSITIONS = 180 * 180
PAPER_TEST_POSITIONS = (1024 // 4) * (2048 // 4)


def equivalent_weight(weight: float, positions: int, paper_positions: int) -> float:
    """The tau (Eq. 4) or sigma (Eq. 10) that has the paper's effect on a map of ``positions``.

    Attention values are about 1 / positions, so ``weight * attention`` keeps its size when the
    weight scales with the number of positions: ``weight * positions / paper_positions``.
    """
    if positions < 1 or paper_positions < 1:
        raise ValueError(f"positions, paper_positions: expected >= 1, got {positions}, {paper_positions}")
    return weight * positions / paper_positions


PAPER_TAU, PAPER_SIGMA = 5e4, 2e4


def paper_tau(positions: int) -> float:
    """The reward weight (Eq. 4) with the paper's effect (tau = 5e4 on 180 x 180 maps) on a map of ``positions``."""
    return equivalent_weight(PAPER_TAU, positions, PAPER_TRAIN_POSITIONS)


def paper_sigma(positions: int) -> float:
    """The ensemble weight (Eq. 10) with the paper's effect (sigma = 2e4 on 256 x 512 maps) on a map of ``positions``."""
    return equivalent_weight(PAPER_SIGMA, positions, PAPER_TEST_POSITIONS)
