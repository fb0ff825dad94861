"""Running SML statistics (CuDAM's L_att k): EMA against a weighted NumPy reference, decay 1 against
``sml.fit_stats``, the score against Eq. 5, and a training run carrying them as the objective's state."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom import sml
from jaxanom.cudam.objective import CuDAM
from jaxanom.sml.running import running_sml_score, running_stats_update
from jaxanom.train import step as step_lib
from jaxanom.train.optim import OptimConfig, make_optimizer
from jaxanom.train.sharding import global_batch, make_mesh, replicated
from jaxanom.train.state import TrainState
from tiny_models import TinySegNet, init_variables, make_batch


def batches(seed, n=4, shape=(2, 5, 6), num_classes=4):
    rng = np.random.default_rng(seed)
    bias = rng.normal(size=num_classes) * 2
    return [((rng.normal(size=shape + (num_classes,)) * 3 + bias).astype(np.float32), rng.random(shape) > 0.2)
            for _ in range(n)]


def weighted_reference(items, decay, num_classes):
    """Per class: pixels of batch t weigh decay^(T-1-t); count = sum w, mean = sum w x / count,
    M2 = sum w (x - mean)^2 (float64)."""
    xs, ws, cs = [], [], []
    for t, (logits, valid) in enumerate(items):
        flat = logits.reshape(-1, num_classes).astype(np.float64)[valid.ravel()]
        xs.append(flat.max(-1))
        cs.append(flat.argmax(-1))
        ws.append(np.full(len(flat), decay ** (len(items) - 1 - t)))
    x, w, c = (np.concatenate(a) for a in (xs, ws, cs))
    count = np.array([w[c == k].sum() for k in range(num_classes)])
    mean = np.array([(w[c == k] * x[c == k]).sum() / max(count[k], 1e-300) for k in range(num_classes)])
    m2 = np.array([(w[c == k] * (x[c == k] - mean[k]) ** 2).sum() for k in range(num_classes)])
    return count, mean, m2


@pytest.mark.parametrize("decay", [1.0, 0.7])
def test_running_statistics_match_weighted_numpy(decay):
    items = batches(0)
    update = jax.jit(running_stats_update, static_argnums=3)
    stats = sml.stats_init(4)
    for logits, valid in items:
        stats = update(stats, logits, valid, decay)
    count, mean, m2 = weighted_reference(items, decay, 4)
    np.testing.assert_allclose(np.asarray(stats.count), count, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(stats.mean), mean, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(stats.m2), m2, rtol=1e-5)


def test_decay_one_is_fit_stats_over_the_same_batches():
    items = batches(1)
    stats = sml.stats_init(4)
    for logits, valid in items:
        stats = running_stats_update(stats, logits, valid, 1.0)
    fitted = sml.fit_stats(items)
    for got, want in zip(stats, fitted):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6, atol=1e-6)


def test_score_is_negated_eq5_with_pooled_fallback_and_zero_when_empty():
    rng = np.random.default_rng(2)
    logits = rng.normal(size=(2, 4, 5, 3)).astype(np.float32) * 3
    stats = sml.ClassStats(jnp.asarray([10.0, 1.0, 0.0]), jnp.asarray([1.0, 5.0, 0.0]), jnp.asarray([18.0, 0.0, 0.0]))
    got = np.asarray(running_sml_score(stats, logits))
    # pooled over all 11 pixels: mean (10 + 5) / 11, M2 = 18 + 10 (1 - m)^2 + (5 - m)^2
    m = 15.0 / 11
    pooled_std = np.sqrt((18 + 10 * (1 - m) ** 2 + (5 - m) ** 2) / 10)
    mean = np.array([1.0, m, m])
    std = np.array([np.sqrt(18 / 9), pooled_std, pooled_std])
    c = logits.argmax(-1)
    np.testing.assert_allclose(got, -(logits.max(-1) - mean[c]) / std[c], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(running_sml_score(sml.stats_init(3), logits)), 0.0)


def test_training_with_decay_one_ends_with_the_batch_fit_of_its_own_predictions():
    model = TinySegNet(head="cudam")
    mesh = make_mesh(jax.devices()[:1])
    tx, _ = make_optimizer(OptimConfig(lr=0.05), 100)
    objective = CuDAM(tau=2.0, attention_k="running_sml", sml_decay=1.0)
    train, _ = step_lib.make_steps(model, tx, objective, mesh)
    state = jax.device_put(TrainState.create(init_variables("cudam"), tx, jax.random.key(1), objective.init_state(3)),
                           replicated(mesh))
    forward = jax.jit(lambda v, x: model.apply(v, x, train=True, mutable=["batch_stats"])[0]["logits"])
    seen = []
    for seed in range(3):
        batch = make_batch(seed)
        seen.append((np.asarray(forward(state.variables, batch["image"])), batch["label"] != 255))
        state, metrics = train(state, global_batch(batch, mesh))
        assert np.isfinite(float(metrics["loss"]))
    fitted = sml.fit_stats(seen)
    for got, want in zip(state.objective_state, fitted):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-5, atol=1e-5)
