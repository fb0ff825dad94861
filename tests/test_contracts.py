"""Every public pixel function composes under the caller's jax.jit / vmap / grad with arrays
closed over or passed in, and gives the eager values; value checks see NaN at any size in host
arrays, and in jax Arrays on request only; dtypes that are not real numbers are refused."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import jaxanom
from host_reads import count_host_reads
from jaxanom import scores, sml
from jaxanom import method_registry
from jaxanom.cudam.score import cudam_score, upsample_attention

B, H, W, C = 2, 9, 11, 5
_rng = np.random.default_rng(0)
LOGITS = jnp.asarray(_rng.normal(size=(B, H, W, C)).astype(np.float32) * 3)
MEAN = jnp.asarray(_rng.normal(size=C).astype(np.float32))
STD = jnp.asarray(_rng.uniform(0.5, 2.0, size=C).astype(np.float32))
SCORE = jnp.asarray(_rng.normal(size=(B, H, W)).astype(np.float32))
PREDICTION = jnp.argmax(LOGITS, axis=-1).astype(jnp.int32)
ATTENTION = jnp.asarray(_rng.uniform(size=(B, H, W)).astype(np.float32))

# name -> (function of one example with everything else closed over, its per-example inputs)
PER_EXAMPLE = {
    "scores.msp": (scores.msp, (LOGITS,)),
    "scores.max_logit": (scores.max_logit, (LOGITS,)),
    "scores.entropy": (lambda x: scores.entropy(x, normalize=True), (LOGITS,)),
    "scores.energy": (lambda x: scores.energy(x, 2.0), (LOGITS,)),
    "scores.softmax_distance": (scores.softmax_distance, (LOGITS,)),
    "sml.standardized_max_logit": (lambda x: sml.standardized_max_logit(x, MEAN, STD), (LOGITS,)),
    "sml.sml_score": (lambda x: sml.sml_score(x, MEAN, STD), (LOGITS,)),
    "sml.postprocess": (lambda s, p: sml.postprocess(s, p), (SCORE, PREDICTION)),
    "sml.suppress_boundaries": (lambda s, p: sml.suppress_boundaries(s, p, 2, 2), (SCORE, PREDICTION)),
    "sml.dilated_smoothing": (sml.dilated_smoothing, (SCORE,)),
    "sml.find_boundaries": (sml.find_boundaries, (PREDICTION,)),
    "sml.boundary_distance": (lambda p: sml.boundary_distance(sml.find_boundaries(p), 3), (PREDICTION,)),
    "sml.stats_update": (lambda x: sml.stats_update(sml.stats_init(C), x), (LOGITS,)),
    "cudam_score": (lambda s, a: cudam_score(s, a, 3.0), (SCORE, ATTENTION)),
    "upsample_attention": (lambda a: upsample_attention(a, (2 * H, 2 * W)), (ATTENTION,)),
}
# name -> (function of a batch, its batched inputs); vmapped over one more leading axis
PER_BATCH = {
    "scores.msp_batch": (scores.msp_batch, (LOGITS,)),
    "scores.max_logit_batch": (scores.max_logit_batch, (LOGITS,)),
    "scores.entropy_batch": (scores.entropy_batch, (LOGITS,)),
    "scores.energy_batch": (lambda x: scores.energy_batch(x, 0.5), (LOGITS,)),
    "scores.softmax_distance_batch": (scores.softmax_distance_batch, (LOGITS,)),
    "sml.sml_score_batch": (lambda x: sml.sml_score_batch(x, MEAN, STD), (LOGITS,)),
    "sml.postprocess_batch": (sml.postprocess_batch, (SCORE, PREDICTION)),
    "sml.stats_update_batch": (lambda x: sml.stats_update_batch(sml.stats_init(C), x), (LOGITS,)),
    **{f"method_registry.score[{name}]": (
        lambda x, name=name: method_registry.score(name, {"logits": x, "stats": (MEAN, STD), "attention": ATTENTION},
                                                   {"cudam_sigma": 2e4}),
        (LOGITS,)) for name in ("msp", "sml", "msp_post", "cudam")},  # one row of each paper
}


def _assert_same(traced, eager):
    for t, e in zip(jax.tree.leaves(traced), jax.tree.leaves(eager), strict=True):
        np.testing.assert_allclose(np.asarray(t), np.asarray(e), rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize("name", sorted(PER_EXAMPLE))
def test_per_example_function_under_user_jit_vmap(name):
    f, inputs = PER_EXAMPLE[name]
    eager = [f(*(x[i] for x in inputs)) for i in range(B)]
    traced = jax.jit(jax.vmap(f))(*inputs)
    for i in range(B):
        _assert_same(jax.tree.map(lambda t: t[i], traced), eager[i])
    closed = jax.jit(lambda: f(*(x[0] for x in inputs)))()  # every array closed over
    _assert_same(closed, eager[0])


@pytest.mark.parametrize("name", sorted(PER_BATCH))
def test_batch_function_under_user_jit_vmap(name):
    f, inputs = PER_BATCH[name]
    eager = f(*inputs)
    stacked = [jnp.stack([x, x[::-1]]) for x in inputs]
    traced = jax.jit(jax.vmap(f))(*stacked)
    _assert_same(jax.tree.map(lambda t: t[0], traced), eager)
    _assert_same(jax.tree.map(lambda t: t[1], traced), f(*(x[::-1] for x in inputs)))


# differentiable in their float inputs; checked against finite differences (an independent reference)
DIFFERENTIABLE = {
    "scores.msp": lambda x: scores.msp(x),
    "scores.max_logit": lambda x: scores.max_logit(x),
    "scores.entropy": lambda x: scores.entropy(x),
    "scores.energy": lambda x: scores.energy(x, 1.5),
    "scores.softmax_distance": lambda x: scores.softmax_distance(x),
    "sml.standardized_max_logit": lambda x: sml.standardized_max_logit(x, MEAN, STD)[0],
}


@pytest.mark.parametrize("name", sorted(DIFFERENTIABLE))
def test_grad_through_public_functions(name):
    f = DIFFERENTIABLE[name]
    x = LOGITS[0].astype(jnp.float32)
    loss = lambda x: jnp.sum(f(x) * jnp.linspace(0.5, 1.5, H * W).reshape(H, W))  # noqa: E731
    check_grads(loss, (x,), order=1, modes=["rev"], eps=1e-2, atol=2e-2, rtol=2e-2)
    np.testing.assert_allclose(jax.jit(jax.grad(loss))(x), jax.grad(loss)(x), rtol=1e-5, atol=1e-6)


def test_grad_through_sml_score_in_logits_and_statistics():
    loss = lambda x, mean, std: jnp.sum(sml.sml_score(x, mean, std, width=2, iterations=2))  # noqa: E731
    check_grads(loss, (LOGITS[0], MEAN, STD), order=1, modes=["rev"], eps=1e-2, atol=2e-2, rtol=2e-2)


@pytest.mark.parametrize("size", [4097, 70_000])
@pytest.mark.parametrize("where", ["one", "all", "inf"])
@pytest.mark.parametrize("array", ["numpy", "jax"])  # NumPy's check; the compiled reduction a jax.Array gets
def test_nan_is_seen_at_any_size(size, where, array):
    logits = np.ones((1, size, 2), np.float32)
    if where == "one":
        logits[0, size - 7, 1] = np.nan
    elif where == "all":
        logits[:] = np.nan
    else:
        logits[0, size // 2, 0] = -np.inf
    logits = logits if array == "numpy" else jnp.asarray(logits)
    with jaxanom.validate_values(array == "jax"):  # a jax.Array is checked on request only
        for f in (scores.max_logit, scores.msp, lambda x: sml.sml_score(x, MEAN[:2], STD[:2], smooth=False)):
            with pytest.raises(ValueError, match="finite"):
                f(logits)
        with pytest.raises(ValueError, match="finite"):
            sml.fit_stats([logits])


def test_closed_over_nan_is_refused_inside_user_jit_on_request():
    bad_mean = MEAN.at[1].set(jnp.nan)
    with jaxanom.validate_values(), pytest.raises(ValueError, match="mean must be finite"):
        jax.jit(jax.vmap(lambda x: sml.sml_score(x, bad_mean, STD)))(LOGITS)


@pytest.mark.parametrize("name", sorted(PER_BATCH))
def test_batch_function_reads_no_device_array_to_check_it(name, monkeypatch):
    """NaN in a jax.Array goes through unread (the batch loops that call these functions never wait
    for the device); inside ``validate_values()`` the same call reads it and refuses it."""
    f, (first, *others) = PER_BATCH[name]
    inputs = (jnp.full_like(first, jnp.nan), *others)
    reads = count_host_reads(monkeypatch)
    jax.block_until_ready(f(*inputs))
    assert reads == []
    with jaxanom.validate_values(), pytest.raises(ValueError, match="must be finite"):
        f(*inputs)
    assert reads


@pytest.mark.parametrize("dtype", [bool, np.complex64])
def test_logits_that_are_not_real_numbers_are_refused(dtype):
    logits = np.ones((H, W, C), dtype)
    for f in (scores.msp, scores.max_logit, lambda x: sml.sml_score(x, MEAN, STD),
              lambda x: sml.stats_update(sml.stats_init(C), x)):
        with pytest.raises(ValueError, match="real"):
            f(logits)
