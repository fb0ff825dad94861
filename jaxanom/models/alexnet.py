"""An AlexNet-style patch encoder (Krizhevsky et al. 2012) with L2-normalised embeddings (docs/papers/offroad.md#patch-encoder).

``PatchAlexNet()(patches)``: (B, s, s, 6) float -> ``{"embedding": (B, D) unit vectors,
"features": (B, hidden)}`` (with ``unit=False`` the embedding is fc2's raw output, e.g. class logits).
Layers: conv5x5 c1, ReLU, maxpool 3/2; conv5x5 c2, ReLU, maxpool
3/2; conv3x3 c3, c4, c5 with ReLU; maxpool 3/2; global average pooling; Dense(hidden), ReLU;
Dense(D); z / ||z||. No BatchNorm (a patch batch mixes frames and domains). ``PATCH_ALEXNET_TINY``
holds the CPU widths.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

PATCH_ALEXNET_TINY = {"widths": (16, 32, 64, 64, 64), "hidden": 64}


class PatchAlexNet(nn.Module):
    """AlexNet layout for small patches; ``widths`` = (c1..c5), ``dim`` = D of the embedding."""

    widths: tuple[int, int, int, int, int] = (64, 192, 384, 256, 256)
    hidden: int = 256
    dim: int = 16
    unit: bool = True

    @nn.compact
    def __call__(self, x: jax.Array) -> dict[str, jax.Array]:
        pool = lambda y: nn.max_pool(y, (3, 3), strides=(2, 2), padding="SAME")  # noqa: E731
        c1, c2, c3, c4, c5 = self.widths
        x = pool(nn.relu(nn.Conv(c1, (5, 5), name="conv1")(x)))
        x = pool(nn.relu(nn.Conv(c2, (5, 5), name="conv2")(x)))
        x = nn.relu(nn.Conv(c3, (3, 3), name="conv3")(x))
        x = nn.relu(nn.Conv(c4, (3, 3), name="conv4")(x))
        x = pool(nn.relu(nn.Conv(c5, (3, 3), name="conv5")(x)))
        features = nn.relu(nn.Dense(self.hidden, name="fc1")(x.mean(axis=(1, 2))))
        z = nn.Dense(self.dim, name="fc2")(features)
        if self.unit:
            z = z / jnp.maximum(jnp.linalg.norm(z, axis=-1, keepdims=True), 1e-12)
        return {"embedding": z, "features": features}
