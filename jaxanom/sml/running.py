"""Running SML statistics during training (CuDAM's attention loss uses them as Eq. 7's k).

The paper weights L_att by ``exp(k)`` with k its anomaly score, SML; SML needs per-class
statistics of the max logit (SML Eqs. 3-4) that do not exist before training ends. Here they
are accumulated from the network's own training predictions P_a (pixels with a valid label)
as training goes, as an exponential moving average carried in the train state:

    count_t = d count_{t-1} + n_t,  and mean / M2 likewise: the old statistics enter the merge
    (Chan et al.'s formula, as ``sml.stats_merge``) as if each old pixel weighed d.

So a pixel seen s steps ago weighs d^s; with ``decay`` d = 1 the running statistics are exactly
``sml.fit_stats`` over the same batches. k = -(L - mean_Y) / std_Y (SML Eq. 5, negated so that
higher = more anomalous) uses the statistics including the current batch; a class with fewer
than 2 pixels or no spread yet uses the statistics of all classes pooled, and k = 0 while no
class has any (e^0 = 1: L_att then weighs every pixel alike).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxanom.sml.stats import ClassStats, _pool, _update_batch


def running_stats_update(stats: ClassStats, logits, valid, decay: float) -> ClassStats:
    """Decay ``stats`` by ``decay`` and merge a batch: logits ``(B, H, W, C)``, bool valid ``(B, H, W)``."""
    decayed = ClassStats(decay * stats.count, stats.mean, decay * stats.m2)
    return _update_batch(decayed, jax.lax.stop_gradient(logits), valid)


def running_sml_score(stats: ClassStats, logits) -> jax.Array:
    """k = -(max logit - mean_Y) / std_Y for logits ``(B, H, W, C)`` -> float32 ``(B, H, W)``, stop-gradient."""
    logits = jax.lax.stop_gradient(logits.astype(jnp.float32))
    total = _pool(*(x[:, None] for x in stats))
    pooled_var = total.m2[0] / jnp.maximum(total.count[0] - 1, 1.0)
    var = stats.m2 / jnp.maximum(stats.count - 1, 1.0)
    own = (stats.count >= 2) & (var > 0)
    mean = jnp.where(own, stats.mean, total.mean[0])
    std = jnp.sqrt(jnp.where(own, var, pooled_var))
    prediction = jnp.argmax(logits, axis=-1)
    z = (jnp.max(logits, axis=-1) - mean[prediction]) / jnp.where(std > 0, std, 1.0)[prediction]
    return jnp.where(pooled_var > 0, -z, 0.0)

