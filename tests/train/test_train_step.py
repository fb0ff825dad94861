"""The pure train / eval steps with every registered objective, the optimizer and data-parallel
sharding (4 simulated CPU devices)."""
import dataclasses
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from sklearn.metrics import confusion_matrix as sk_confusion

from jaxanom.cudam.objective import CuDAM
from jaxanom.cudam.score import paper_tau
from jaxanom.losses import CrossEntropy, cross_entropy
from jaxanom.msaam.objective import MSAAM
from jaxanom.config_codec import decode
from jaxanom.objectives import Objective, objective_names, register
from jaxanom.train import step as step_lib
from jaxanom.train.segmenter import TrainConfig
from jaxanom.train.optim import OptimConfig, make_optimizer
from jaxanom.train.sharding import global_batch, make_mesh, replicated
from jaxanom.train.state import TrainState
from tiny_models import TinySegNet, init_variables, make_batch

KEY = jax.random.key(7)
# the TinySegNet head that produces what an objective reads (a new objective's needs go here too)
HEADS = {(): "plain", ("attention",): "cudam", ("branch_weights",): "msaam"}


def head_for(name: str) -> str:
    return HEADS[Objective.class_named(name).needs]


@functools.lru_cache(maxsize=None)
def compiled(name, n_devices, lr, compute_dtype="float32"):
    """Model, mesh, optimizer, objective (registered ``name``, defaults) and the jitted steps; built once."""
    model = TinySegNet(head=head_for(name))
    mesh = make_mesh(jax.devices()[:n_devices])
    tx, _ = make_optimizer(OptimConfig(lr=lr), 100)
    objective = Objective.class_named(name)()
    return (model, mesh, tx, objective) + step_lib.make_steps(model, tx, objective, mesh, compute_dtype=compute_dtype)


def setup(name="cross_entropy", n_devices=4, lr=0.05, **kwargs):
    """As ``compiled`` plus a fresh step-0 state (states are donated, so never shared)."""
    model, mesh, tx, objective, train, evaluate = compiled(name, n_devices, lr, **kwargs)
    state = TrainState.create(init_variables(model.head), tx, jax.random.key(1), objective.init_state(3))
    return model, mesh, tx, objective, jax.device_put(state, replicated(mesh)), train, evaluate


@register
@dataclasses.dataclass(frozen=True)
class CountingCrossEntropy(Objective):
    """A user's objective: cross-entropy that counts its steps in its own state."""

    name: str = dataclasses.field(default="test_counting_cross_entropy", init=False)

    def init_state(self, num_classes):
        return {"steps": jnp.zeros((), jnp.int32), "per_class": jnp.zeros(num_classes)}

    def loss(self, outputs, batch, key, state, ignore):
        state = {"steps": state["steps"] + 1, "per_class": state["per_class"] + 1.0}
        return cross_entropy(outputs["logits"], batch["label"], ignore), {"seen": state["steps"]}, state


@pytest.mark.parametrize("name", objective_names())
def test_every_objective_trains_threads_its_state_and_lowers_the_cross_entropy(name):
    """30 steps on a fixed batch; judged by the cross-entropy of the network's own logits, since an
    objective's loss need not fall monotonically (CuDAM's alternates between rewarded and plain steps)."""
    model, mesh, _, objective, state, train, _ = setup(name)
    batch = make_batch(0)
    forward = jax.jit(lambda v: cross_entropy(model.apply(v, batch["image"])["logits"], batch["label"]))
    before = float(forward(jax.device_get(state.variables)))
    losses = []
    for _ in range(30):
        old = state
        state, metrics = train(state, global_batch(batch, mesh))
        assert jax.tree.structure(state) == jax.tree.structure(old)
        losses.append(float(metrics["loss"]))
    assert np.all(np.isfinite(losses))
    assert {value.dtype for value in metrics.values()} == {jnp.dtype(jnp.float32)}
    assert float(forward(jax.device_get(state.variables))) < 0.75 * before
    assert int(state.step) == 30


@pytest.mark.parametrize("name", objective_names())
def test_every_objective_round_trips_through_its_dict_and_refuses_an_unknown_field(name):
    cls = Objective.class_named(name)
    weighted = "class_weights" in {f.name for f in dataclasses.fields(cls)}
    objective = cls(class_weights=(1.0, 2.0, 0.5)) if weighted else cls()
    values = dataclasses.asdict(objective)
    assert values["name"] == name
    read = decode(Objective, {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}, "objective")
    assert read == objective
    with pytest.raises(ValueError, match=f"objective.bogus: unknown field of {cls.__name__}"):
        decode(Objective, {**values, "bogus": 1}, "objective")


def test_unknown_objective_names_the_known_ones():
    with pytest.raises(ValueError, match=r"objective.name: expected one of \('cross_entropy', 'cudam', 'msaam'.*'pebal'"):
        decode(Objective, {"name": "pebal"}, "objective")


def test_an_objective_from_outside_the_package_is_registered_and_its_state_threaded():
    assert "test_counting_cross_entropy" in objective_names()
    assert decode(Objective, {"name": "test_counting_cross_entropy"}, "objective") == CountingCrossEntropy()
    _, mesh, _, _, state, train, _ = setup("test_counting_cross_entropy")  # compiled by the test above
    for seed in range(2):
        state, metrics = train(state, global_batch(make_batch(seed), mesh))
    assert int(state.objective_state["steps"]) == 2 and float(metrics["seen"]) == 2
    np.testing.assert_array_equal(state.objective_state["per_class"], [2.0, 2.0, 2.0])

    @dataclasses.dataclass(frozen=True)
    class Impostor(Objective):
        name: str = dataclasses.field(default="cudam", init=False)

    with pytest.raises(ValueError, match="'cudam': already registered by CuDAM"):
        register(Impostor)
    with pytest.raises(ValueError, match="name: str"):
        register(dataclasses.dataclass(frozen=True)(type("Nameless", (Objective,), {})))


@pytest.mark.parametrize("name", ["cudam", "msaam"])
def test_a_network_without_the_output_an_objective_reads_is_refused_when_traced(name):
    model, objective = TinySegNet(), Objective.class_named(name)()
    tx, _ = make_optimizer(OptimConfig(lr=0.05), 100)
    state = TrainState.create(init_variables(), tx, jax.random.key(0), objective.init_state(3))
    step = functools.partial(step_lib.train_step, model=model, tx=tx, objective=objective)
    with pytest.raises(ValueError, match=rf"objective '{name}' reads the model output\(s\) \['{objective.needs[0]}'\]"
                                         r", which TinySegNet does not produce \(its outputs: \['logits'\]\)"):
        jax.eval_shape(step, state, make_batch(0))


def test_cudam_objective_owns_the_paper_equivalent_tau():
    """tau=None is the paper's 5e4 rescaled to the map's h * w (here 4 x 4), whoever calls the loss."""
    rng = np.random.default_rng(0)
    logits = jnp.asarray(rng.normal(size=(2, 8, 8, 3)) * 3, jnp.float32)
    z = rng.normal(size=(2, 16))
    attention = jnp.asarray((np.exp(z) / np.exp(z).sum(1, keepdims=True)).reshape(2, 4, 4), jnp.float32)
    batch, key = {"label": make_batch(0, batch=2)["label"]}, jax.random.key(3)

    def loss(objective):
        return float(jax.jit(lambda: objective.loss({"logits": logits, "attention": attention}, batch, key, None,
                                                    255)[1]["seg_loss"])())

    rewarded = CuDAM(reward_prob=1.0)
    assert rewarded.reward_weight(16) == paper_tau(16) == pytest.approx(5e4 * 16 / (180 * 180))
    assert loss(rewarded) == loss(dataclasses.replace(rewarded, tau=paper_tau(16)))
    assert loss(rewarded) != loss(dataclasses.replace(rewarded, tau=5e4))


@pytest.mark.parametrize("objective", [CuDAM(reward_prob=0.0, beta=0.0), MSAAM(lam=0.0)], ids=["cudam", "msaam"])
def test_an_attention_objective_with_its_terms_off_is_the_cross_entropy_bitwise(objective):
    """CuDAM Table III's "attention" row (the CuDAM network trained by L_seg alone), and what a run of
    an earlier version trained with the plain loss on a CuDAM or MSAAM network reads as: the same
    loss and logits gradient to the bit, no gradient into the module's output."""
    rng = np.random.default_rng(2)  # not make_batch's seed: its labels are the argmax of its draws
    outputs = {"logits": jnp.asarray(rng.normal(size=(2, 8, 8, 3)) * 3, jnp.float32),
               "attention": jnp.asarray(rng.dirichlet(np.ones(16), 2).reshape(2, 4, 4), jnp.float32),
               "branch_weights": jnp.asarray(rng.dirichlet(np.ones(3), 2), jnp.float32)}
    batch = {"label": make_batch(1, batch=2)["label"]}

    def value_and_grad(objective):
        loss = lambda out, key: objective.loss(out, batch, key, None, 255)[0]  # noqa: E731
        return jax.jit(jax.vmap(jax.value_and_grad(loss), in_axes=(None, 0)))(outputs, jax.random.split(KEY, 8))

    plain, plain_grad = value_and_grad(CrossEntropy())
    value, grad = value_and_grad(objective)  # 8 steps' keys: never a study one
    np.testing.assert_array_equal(plain, value)
    np.testing.assert_array_equal(plain_grad["logits"], grad["logits"])
    np.testing.assert_array_equal(grad[objective.needs[0]], 0.0)


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
    model, mesh, tx, objective, state, _, _ = setup("cudam")

    @chex.assert_max_traces(n=1)
    def traced(state, batch):
        return step_lib.train_step(state, batch, model=model, tx=tx, objective=objective)

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
    (lambda: CuDAM(reward_prob=1.5), "reward_prob"),
    (lambda: CuDAM(tau=-1.0), "tau"),
    (lambda: CuDAM(attention_k="sml"), "attention_k"),
    (lambda: CuDAM(sml_decay=0.0), "sml_decay"),
    (lambda: MSAAM(lam=float("nan")), "lam"),
    (lambda: CrossEntropy(class_weights=(1.0, -1.0)), r"class_weights\[1\]"),
    (lambda: TrainConfig(run_dir="", compute_dtype="float16"), "compute_dtype"),
    (lambda: TrainConfig(run_dir="", objective="cudam"), "objective: expected a jaxanom.objectives.Objective"),
    (lambda: step_lib.make_steps(TinySegNet(), None, CrossEntropy(), make_mesh(), compute_dtype="half"),
     "compute_dtype"),
    (lambda: make_optimizer(OptimConfig(warmup_steps=10), steps=10), "steps"),
    (lambda: global_batch({"image": np.zeros((3, 8, 8, 3))}, make_mesh()), "image"),
])
def test_bad_settings_raise_value_error(make, name):
    with pytest.raises(ValueError, match=name):
        make()
