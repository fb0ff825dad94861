"""conv2d_patches and Conv2D against PyTorch's conv2d in float64: values and gradients, odd sizes,
strides, dilations past the image, 1x1 and 7x7 kernels; Conv2D's parameters are nn.Conv's."""
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.nn.conv import Conv2D, conv2d_patches

torch = pytest.importorskip("torch")

# (H, W, k, stride, dilation): odd and tiny sizes, stride 2 on odd sides, dilations whose outer
# taps read only padding (12 and 36 on 8x8, as DeepLab's ASPP at output stride 8), a 7x7 stem.
CASES = [(8, 8, 3, 1, 12), (8, 8, 3, 1, 36), (9, 7, 3, 2, 1), (15, 17, 7, 2, 1), (8, 8, 1, 2, 1),
         (5, 6, 3, 1, 2), (1, 1, 3, 1, 1), (6, 5, 1, 1, 1), (4, 4, 3, 1, 3)]


def _torch_conv(x, kernel, stride, dilation):
    pad = dilation * (kernel.shape[0] - 1) // 2
    x_t = torch.tensor(x, requires_grad=True)
    k_t = torch.tensor(kernel, requires_grad=True)
    y = torch.nn.functional.conv2d(x_t.permute(0, 3, 1, 2), k_t.permute(3, 2, 0, 1), stride=stride,
                                   padding=pad, dilation=dilation).permute(0, 2, 3, 1)
    return x_t, k_t, y


@pytest.mark.parametrize("h, w, k, stride, dilation", CASES)
def test_conv2d_patches_matches_torch_values_and_gradients(h, w, k, stride, dilation):
    rng = np.random.default_rng(h * 100 + k)
    x = rng.normal(size=(2, h, w, 5)) * 1e3  # large values
    kernel = rng.normal(size=(k, k, 5, 4))
    x_t, k_t, y_t = _torch_conv(x, kernel, stride, dilation)
    cot = rng.normal(size=tuple(y_t.shape))
    y_t.backward(torch.tensor(cot))
    pad = dilation * (k - 1) // 2
    with jax.enable_x64(True):
        y, vjp = jax.vjp(lambda a, b: conv2d_patches(a, b, stride, dilation, pad), jnp.asarray(x), jnp.asarray(kernel))
        dx, dk = vjp(jnp.asarray(cot))
    np.testing.assert_allclose(np.asarray(y), y_t.detach().numpy(), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.asarray(dx), x_t.grad.numpy(), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.asarray(dk), k_t.grad.numpy(), rtol=1e-12, atol=1e-6)


def test_conv2d_module_keeps_nn_conv_parameters_and_matches_it_in_float32(monkeypatch):
    monkeypatch.setattr("jaxanom.nn.conv.MIN_PATCH_CHANNELS", 1)  # the patch path, at any width
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(2, 9, 11, 16)).astype(np.float32))
    ours = Conv2D(8, 3, stride=2, dilation=1)
    flax_conv = nn.Conv(8, (3, 3), strides=2, padding=((1, 1), (1, 1)), use_bias=False,
                        kernel_init=nn.initializers.variance_scaling(2.0, "fan_out", "normal"))
    params = ours.init(jax.random.key(3), x)
    reference = flax_conv.init(jax.random.key(3), x)
    assert jax.tree.map(np.shape, params) == jax.tree.map(np.shape, reference)
    np.testing.assert_array_equal(params["params"]["kernel"], reference["params"]["kernel"])
    got, want = ours.apply(params, x), flax_conv.apply(params, x)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(jnp.abs(want).max()))


def test_conv2d_module_computes_in_its_dtype():
    x = jnp.ones((1, 4, 4, 3), jnp.float32)
    module = Conv2D(2, 3, dtype=jnp.bfloat16)
    params = module.init(jax.random.key(0), x)
    assert params["params"]["kernel"].dtype == jnp.float32
    assert module.apply(params, x).dtype == jnp.bfloat16


def test_backward_keeps_the_input_not_its_patches():
    x, kernel = jnp.ones((2, 16, 16, 8)), jnp.ones((3, 3, 8, 4))
    _, backward = jax.vjp(lambda a, b: conv2d_patches(a, b, 1, 2, 2), x, kernel)
    kept = sum(leaf.size for leaf in jax.tree.leaves(backward) if hasattr(leaf, "size"))
    assert kept <= x.size + kernel.size  # the patches alone would be 9 * x.size


def test_conv2d_module_takes_patches_only_for_wide_inputs_whose_patches_fit(monkeypatch):
    x = jnp.asarray(np.random.default_rng(1).normal(size=(1, 6, 7, 4)).astype(np.float32))
    module = Conv2D(3, 3, dilation=2)
    params = module.init(jax.random.key(0), x)
    primitives = lambda: {str(e.primitive) for e in jax.make_jaxpr(module.apply)(params, x).jaxpr.eqns}  # noqa: E731
    assert "conv_general_dilated" in primitives()  # 4 input channels: narrower than MIN_PATCH_CHANNELS
    narrow = module.apply(params, x)
    monkeypatch.setattr("jaxanom.nn.conv.MIN_PATCH_CHANNELS", 4)
    assert "conv_general_dilated" not in primitives()
    np.testing.assert_allclose(module.apply(params, x), narrow, rtol=1e-5, atol=1e-5)
    monkeypatch.setattr("jaxanom.nn.conv.MAX_PATCH_BYTES", x.nbytes * 9 - 1)
    assert "conv_general_dilated" in primitives()
