"""CuDAM's attention module (Eqs. 1-3) against NumPy references written from the paper."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.cudam.attention import CuDAMAttention, channel_max
from attention_reference import as_np, cudam_reference

RNG = np.random.default_rng(0)
KEY = jax.random.key(0, impl="rbg")  # cheap to compile on CPU


@pytest.fixture(scope="module")
def cudam_case():
    f_a = RNG.normal(size=(2, 6, 7, 5)).astype(np.float32)
    f_low = RNG.normal(size=(2, 6, 7, 3)).astype(np.float32)
    f_mid = RNG.normal(size=(2, 3, 4, 4)).astype(np.float32)
    module = CuDAMAttention()
    params = jax.jit(module.init)(KEY, f_a, f_low, f_mid)["params"]
    return module, params, (f_a, f_low, f_mid)


def test_cudam_init_alpha_zero_returns_input_exactly(cudam_case):
    module, params, (f_a, f_low, f_mid) = cudam_case
    assert float(params["alpha"]) == 0.0
    features, _ = jax.jit(module.apply)({"params": params}, f_a, f_low, f_mid)
    np.testing.assert_array_equal(np.asarray(features), f_a)


@pytest.mark.parametrize("jit", [True, False], ids=["jit", "eager"])
def test_cudam_matches_numpy_reference(cudam_case, jit):
    module, params, inputs = cudam_case
    params = {**params, "alpha": jnp.float32(3.5)}
    # scale the attention conv up so the map is far from uniform
    params["attention_conv"] = {**params["attention_conv"], "kernel": params["attention_conv"]["kernel"] * 5}
    apply = jax.jit(module.apply) if jit else module.apply
    features, att = apply({"params": params}, *inputs)
    want_f, want_att = cudam_reference(as_np(params), *(x.astype(np.float64) for x in inputs))
    np.testing.assert_allclose(att, want_att, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(features, want_f, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(att).sum((1, 2)), 1.0, rtol=1e-6)
    assert np.ptp(want_att) > 1e-3  # the case is not trivially uniform


def test_cudam_attention_sums_to_one_with_huge_features(cudam_case):
    module, params, (f_a, f_low, f_mid) = cudam_case
    _, att = jax.jit(module.apply)({"params": params}, f_a * 1e4, f_low, f_mid)
    assert np.isfinite(att).all()
    np.testing.assert_allclose(np.asarray(att).sum((1, 2)), 1.0, rtol=1e-6)


@pytest.mark.parametrize("scale", [1.0, 1e30], ids=["unit", "huge"])
def test_channel_max_is_the_max_and_tied_channels_share_its_gradient(scale):
    x = (RNG.integers(-2, 3, size=(3, 5, 7, 4)) * scale).astype(np.float32)  # many ties
    weight = RNG.normal(size=x.shape[:-1]).astype(np.float32)
    value, grad = jax.jit(jax.value_and_grad(lambda x: jnp.sum(weight * channel_max(x))))(x)
    np.testing.assert_array_equal(jax.jit(channel_max)(x), x.max(-1))
    is_top = x == x.max(-1, keepdims=True)
    np.testing.assert_allclose(grad, is_top * (weight / is_top.sum(-1))[..., None], rtol=1e-6)
    np.testing.assert_allclose(value, np.sum(weight.astype(np.float64) * x.max(-1)), rtol=1e-5)
    assert (is_top.sum(-1) > 1).any()  # the case has ties


def test_scale_free_gate_is_eq3_with_alpha_times_hw():
    rng = np.random.default_rng(1)
    f_a = rng.normal(size=(2, 5, 7, 4)).astype(np.float32)
    f_low = rng.normal(size=(2, 5, 7, 3)).astype(np.float32)
    f_mid = rng.normal(size=(2, 3, 4, 2)).astype(np.float32)
    module = CuDAMAttention(gate="scale_free")
    params = jax.jit(module.init)(KEY, f_a, f_low, f_mid)["params"]
    params = {**params, "alpha": jnp.float32(0.3)}
    params["attention_conv"] = {**params["attention_conv"], "kernel": params["attention_conv"]["kernel"] * 5}
    features, att = jax.jit(module.apply)({"params": params}, f_a, f_low, f_mid)
    reference = as_np(params)
    reference["alpha"] = 0.3 * 5 * 7  # h * w
    want_f, want_att = cudam_reference(reference, *(x.astype(np.float64) for x in (f_a, f_low, f_mid)))
    np.testing.assert_allclose(att, want_att, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(features, want_f, rtol=1e-5, atol=1e-5)
    # the map averages 1 per position: alpha * mean(h w M) = alpha, at any size
    np.testing.assert_allclose(np.asarray(att).mean((1, 2)) * 35, 1.0, rtol=1e-6)


def test_unknown_gate_is_rejected():
    with pytest.raises(ValueError, match="gate"):
        CuDAMAttention(gate="sigmoid")
