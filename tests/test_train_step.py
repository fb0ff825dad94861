"""The pure train / eval steps, the optimizer and data-parallel sharding (4 simulated CPU devices)."""
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from sklearn.metrics import confusion_matrix as sk_confusion

from jaxanom.train import step as step_lib
from jaxanom.train.optim import OptimConfig, make_optimizer
from jaxanom.train.sharding import global_batch, make_mesh, replicated
from jaxanom.train.state import TrainState
from tiny_models import TinySegNet, init_variables, make_batch


@functools.lru_cache(maxsize=None)
def compiled(head, n_devices, lr, compute_dtype="float32"):
    """Model, mesh, optimizer, loss config and the jitted steps; built once per setting."""
    model = TinySegNet(head=head)
    mesh = make_mesh(jax.devices()[:n_devices])
    tx, _ = make_optimizer(OptimConfig(lr=lr), 100)
    cfg = step_lib.LossConfig(method=head, compute_dtype=compute_dtype)
    return (model, mesh, tx, cfg) + step_lib.make_steps(model, tx, cfg, mesh)


def setup(head="plain", n_devices=4, lr=0.05, **kwargs):
    """As ``compiled`` plus a fresh step-0 state (states are donated, so never shared)."""
    model, mesh, tx, cfg, train, evaluate = compiled(head, n_devices, lr, **kwargs)
    state = jax.device_put(TrainState.create(init_variables(head), tx, jax.random.key(1)), replicated(mesh))
    return model, mesh, tx, cfg, state, train, evaluate


@pytest.mark.parametrize("head", ["plain", "msaam"])
def test_loss_falls_over_30_steps_on_a_fixed_batch(head):
    _, mesh, _, _, state, train, _ = setup(head, lr=0.1)
    batch = global_batch(make_batch(0), mesh)
    history = []
    for _ in range(30):
        state, metrics = train(state, batch)
        history.append(float(metrics["loss"]))
    assert np.all(np.isfinite(history))
    assert history[-1] < 0.5 * history[0]
    assert int(state.step) == 30


def test_four_devices_step_equals_one_device_step():
    assert jax.device_count() == 4
    results = []
    for n_devices in (1, 4):
        _, mesh, _, _, state, train, _ = setup("cudam", n_devices)
        for seed in range(3):
            state, metrics = train(state, global_batch(make_batch(seed), mesh))
        results.append((jax.device_get(state.params), jax.device_get(state.batch_stats), float(metrics["loss"])))
    (p1, s1, l1), (p4, s4, l4) = results
    chex.assert_trees_all_close(p1, p4, rtol=1e-5, atol=1e-6)
    chex.assert_trees_all_close(s1, s4, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(l1, l4, rtol=1e-5)


def test_cudam_step_compiles_once_donates_the_state_off_the_cpu_and_draws_study_iterations():
    model, mesh, tx, cfg, state, _, _ = setup("cudam")

    @chex.assert_max_traces(n=1)
    def traced(state, batch):
        return step_lib.train_step(state, batch, model=model, tx=tx, cfg=cfg)

    train = step_lib.jit_train_step(traced, mesh)  # as make_steps does
    studies = []
    for seed in range(30):
        old = state
        state, metrics = train(state, global_batch(make_batch(seed % 3), mesh))  # a second trace raises
        assert jax.tree.leaves(old.params)[0].is_deleted() == (jax.default_backend() != "cpu")
        assert all(np.isfinite(float(v)) for v in metrics.values())
        assert 0.0 <= float(metrics["lambda"]) <= 1.0
        studies.append(float(metrics["study"]))
    assert train._cache_size() == 1
    assert 0 < sum(studies) < 30  # reward_prob 0.5: both study and exam iterations occur


def test_bfloat16_compute_keeps_float32_master_weights():
    _, mesh, _, _, state, train, _ = setup("cudam", compute_dtype="bfloat16")
    for seed in range(3):
        state, metrics = train(state, global_batch(make_batch(seed), mesh))
    assert np.isfinite(float(metrics["loss"]))
    assert {leaf.dtype for leaf in jax.tree.leaves((state.params, state.batch_stats))} == {jnp.dtype(jnp.float32)}


def test_eval_step_confusion_matches_sklearn_and_never_rewards():
    model, mesh, _, _, state, _, evaluate = setup("cudam")
    batch = make_batch(5, num_classes=3, void_fraction=0.3)
    confusion = np.asarray(evaluate(state.variables, global_batch(batch, mesh)))
    logits = model.apply(jax.device_get(state.variables), batch["image"], train=False)["logits"]
    prediction = np.argmax(np.asarray(logits), -1)
    valid = batch["label"] != 255
    expected = sk_confusion(batch["label"][valid], prediction[valid], labels=[0, 1, 2])
    np.testing.assert_array_equal(confusion, expected)


def ref_poly_lr(step, lr, warmup, total, power=0.9):
    if step < warmup:
        return lr * step / warmup
    return lr * (1 - (step - warmup) / (total - warmup)) ** power


def test_schedule_is_linear_warmup_then_poly():
    _, lr_at = make_optimizer(OptimConfig(lr=0.02, warmup_steps=10), steps=110)
    for step in [0, 1, 5, 9, 10, 11, 50, 109, 110]:
        np.testing.assert_allclose(float(lr_at(step)), ref_poly_lr(step, 0.02, 10, 110), rtol=1e-5, atol=1e-9)
    _, lr_at = make_optimizer(OptimConfig(lr=0.02, accum_steps=4), steps=400)
    np.testing.assert_allclose(float(lr_at(7)), ref_poly_lr(1, 0.02, 0, 100), rtol=1e-6)


def test_weight_decay_applies_to_kernels_only():
    params = init_variables("cudam")["params"]
    params = jax.tree.map(lambda p: p + 1.0, params)  # non-zero biases and scales
    zeros = jax.tree.map(jnp.zeros_like, params)
    for name in ("sgd", "adamw"):
        tx, lr_at = make_optimizer(OptimConfig(name=name, lr=0.1, weight_decay=0.01), steps=10)
        updates, _ = jax.jit(tx.update)(zeros, tx.init(params), params)
        for path, update in jax.tree_util.tree_leaves_with_path(updates):
            param = functools.reduce(lambda t, k: t[k.key], path, params)
            expected = -0.1 * 0.01 * np.asarray(param) if param.ndim >= 2 else np.zeros(param.shape)
            np.testing.assert_allclose(update, expected, rtol=1e-6, atol=1e-12, err_msg=f"{name} {path}")


def test_sgd_matches_pytorch_style_momentum_with_l2():
    params = {"kernel": jnp.array([[1.0, -2.0]]), "bias": jnp.array([0.5])}
    tx, _ = make_optimizer(OptimConfig(lr=0.1, weight_decay=0.01, momentum=0.9), steps=1000)
    opt_state, update = tx.init(params), jax.jit(tx.update)
    p = {k: np.asarray(v, np.float64) for k, v in params.items()}
    buf = {k: np.zeros_like(v) for k, v in p.items()}
    rng = np.random.default_rng(8)
    for t in range(3):
        grads = {k: rng.normal(size=v.shape) for k, v in p.items()}
        updates, opt_state = update(jax.tree.map(jnp.asarray, grads), opt_state, params)
        params = jax.jit(optax.apply_updates)(params, updates)
        lr = 0.1 * (1 - t / 1000) ** 0.9
        for k in p:  # torch.optim.SGD: d = g + wd * p; buf = momentum * buf + d; p -= lr * buf
            d = grads[k] + (0.01 * p[k] if k == "kernel" else 0)
            buf[k] = 0.9 * buf[k] + d
            p[k] = p[k] - lr * buf[k]
    for k in p:
        np.testing.assert_allclose(params[k], p[k], rtol=1e-5)


def test_accumulation_averages_k_gradients_and_clipping_bounds_the_norm():
    params = {"kernel": jnp.ones((2, 2))}
    g1, g2 = {"kernel": jnp.full((2, 2), 2.0)}, {"kernel": jnp.full((2, 2), -1.0)}
    plain, _ = make_optimizer(OptimConfig(lr=0.1, weight_decay=0.0), steps=100)
    accum, _ = make_optimizer(OptimConfig(lr=0.1, weight_decay=0.0, accum_steps=2), steps=200)
    state = accum.init(params)
    first, state = jax.jit(accum.update)(g1, state, params)
    assert np.all(np.asarray(first["kernel"]) == 0)
    second, _ = jax.jit(accum.update)(g2, state, params)
    expected, _ = jax.jit(plain.update)({"kernel": jnp.full((2, 2), 0.5)}, plain.init(params), params)
    np.testing.assert_allclose(second["kernel"], expected["kernel"], rtol=1e-6)

    clipped, _ = make_optimizer(OptimConfig(lr=1.0, momentum=0.0, weight_decay=0.0, clip_norm=1.0), steps=10)
    update, _ = jax.jit(clipped.update)({"kernel": jnp.full((2, 2), 10.0)}, clipped.init(params), params)
    np.testing.assert_allclose(np.linalg.norm(update["kernel"]), 1.0, rtol=1e-6)


@pytest.mark.parametrize("make, name", [
    (lambda: OptimConfig(name="adam"), "name"),
    (lambda: OptimConfig(accum_steps=0), "accum_steps"),
    (lambda: step_lib.LossConfig(method="pebal"), "method"),
    (lambda: step_lib.LossConfig(reward_prob=1.5), "reward_prob"),
    (lambda: make_optimizer(OptimConfig(warmup_steps=10), steps=10), "steps"),
    (lambda: global_batch({"image": np.zeros((3, 8, 8, 3))}, make_mesh()), "image"),
])
def test_bad_settings_raise_value_error(make, name):
    with pytest.raises(ValueError, match=name):
        make()
