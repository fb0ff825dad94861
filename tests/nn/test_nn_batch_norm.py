"""BatchNorm (closed-form training gradient) against flax's nn.BatchNorm (autodiff) and PyTorch's
batch_norm in float64: outputs, gradients of input, scale and bias, running averages; awkward
inputs (a constant channel, one value per channel, a large offset, rank 2 and 4)."""
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.nn.batch_norm import BatchNorm

torch = pytest.importorskip("torch")

MOMENTUM, EPSILON = 0.9, 1e-5


def _inputs(shape, seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=shape) * 3.0 + 1e3  # a large offset: E[x^2] - E[x]^2 cancels
    x[..., 0] = 7.0  # a constant channel: zero variance
    channels = shape[-1]
    variables = {"params": {"scale": rng.uniform(0.5, 2.0, channels), "bias": rng.normal(size=channels)},
                 "batch_stats": {"mean": rng.normal(size=channels), "var": rng.uniform(0.5, 2.0, channels)}}
    return x, rng.normal(size=shape), variables


def _apply(module, variables, x, cotangent, train):
    """Output, gradients wrt (x, scale, bias) of <output, cotangent>, and the new batch_stats."""
    def loss(x, params):
        y, state = module.apply({"params": params, "batch_stats": variables["batch_stats"]}, x,
                                mutable=["batch_stats"])
        return jnp.sum(y * cotangent), (y, state["batch_stats"])

    (_, (y, stats)), (dx, dparams) = jax.value_and_grad(loss, (0, 1), has_aux=True)(x, variables["params"])
    return y, dx, dparams["scale"], dparams["bias"], stats


@pytest.mark.parametrize("shape", [(2, 5, 3, 4), (6, 3), (1, 1, 1, 3), (3, 7, 5, 2)])
@pytest.mark.parametrize("train", [True, False])
def test_matches_flax_batch_norm_in_float64(shape, train):
    x, cotangent, variables = _inputs(shape, seed=sum(shape))
    with jax.enable_x64(True):
        variables = jax.tree.map(jnp.asarray, variables)
        ours = BatchNorm(not train, MOMENTUM, EPSILON, jnp.float64)
        flax_bn = nn.BatchNorm(use_running_average=not train, momentum=MOMENTUM, epsilon=EPSILON,
                               dtype=jnp.float64, param_dtype=jnp.float64)
        got = _apply(ours, variables, jnp.asarray(x), jnp.asarray(cotangent), train)
        want = _apply(flax_bn, variables, jnp.asarray(x), jnp.asarray(cotangent), train)
    # flax's gradient goes through E[x^2] - E[x]^2 at a 1e3 offset: about 1e-7 relative error
    got, want = jax.device_get((got, want))
    for name, a, b in zip(("y", "dx", "dscale", "dbias"), got[:4], want[:4]):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6 * np.abs(b).max(), err_msg=name)
    for key in ("mean", "var"):
        np.testing.assert_allclose(got[4][key], want[4][key], rtol=1e-9, atol=1e-9, err_msg=key)


@pytest.mark.parametrize("shape", [(2, 5, 3, 4), (6, 3)])
def test_training_matches_torch_batch_norm_in_float64(shape):
    x, cotangent, variables = _inputs(shape, seed=1)
    x -= 1e3  # PyTorch's two-pass variance is exact at any offset; flax's formula is not
    with jax.enable_x64(True):
        y, dx, dscale, dbias, _ = _apply(BatchNorm(False, MOMENTUM, EPSILON, jnp.float64),
                                         jax.tree.map(jnp.asarray, variables), jnp.asarray(x),
                                         jnp.asarray(cotangent), True)
    x_t = torch.tensor(np.moveaxis(x, -1, 1), requires_grad=True)
    scale_t = torch.tensor(variables["params"]["scale"], requires_grad=True)
    bias_t = torch.tensor(variables["params"]["bias"], requires_grad=True)
    y_t = torch.nn.functional.batch_norm(x_t, None, None, scale_t, bias_t, training=True, eps=EPSILON)
    y_t.backward(torch.tensor(np.moveaxis(cotangent, -1, 1)))
    np.testing.assert_allclose(y, np.moveaxis(y_t.detach().numpy(), 1, -1), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(dx, np.moveaxis(x_t.grad.numpy(), 1, -1), rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(dscale, scale_t.grad.numpy(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(dbias, bias_t.grad.numpy(), rtol=1e-9, atol=1e-9)


def test_bfloat16_output_float32_statistics_and_variables():
    x = jnp.asarray(np.random.default_rng(0).normal(size=(2, 4, 4, 3)), jnp.bfloat16)
    module = BatchNorm(False, MOMENTUM, EPSILON, jnp.bfloat16)
    variables = module.init(jax.random.key(0), x)
    y, state = module.apply(variables, x, mutable=["batch_stats"])
    assert y.dtype == jnp.bfloat16
    assert {leaf.dtype for leaf in jax.tree.leaves((variables, state))} == {jnp.dtype(jnp.float32)}
    want_mean = 0.1 * np.asarray(x, np.float32).mean((0, 1, 2))
    np.testing.assert_allclose(state["batch_stats"]["mean"], want_mean, rtol=1e-6, atol=1e-7)
