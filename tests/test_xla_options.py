"""conv_compiler_options: XLA's own convolutions on the CPU, results within float32 rounding."""
import jax
import numpy as np
import pytest

from jaxanom.xla_options import conv_compiler_options, state_donation


def _conv(x, k, dilation):
    return jax.lax.conv_general_dilated(x, k, (1, 1), [(dilation, dilation)] * 2, rhs_dilation=(dilation,) * 2,
                                        dimension_numbers=("NHWC", "HWIO", "NHWC"))


def test_no_options_off_the_cpu():
    assert conv_compiler_options("gpu") == {} and conv_compiler_options("tpu") == {}


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="CPU compiler options")
@pytest.mark.parametrize("dilation", [1, 2])
def test_cpu_convolution_matches_torch_without_ynnpack(dilation):
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(1, 15, 17, 32)).astype(np.float32) * np.float32(1e3)  # odd sizes, large values
    k = rng.normal(size=(3, 3, 32, 24)).astype(np.float32)  # large enough for YNNPACK by default
    fn = jax.jit(_conv, static_argnums=2, compiler_options=conv_compiler_options())
    compiled = fn.lower(x, k, dilation).compile()
    assert "__ynn_fusion" not in compiled.as_text()
    got = np.asarray(fn(x, k, dilation))
    want = torch.nn.functional.conv2d(torch.from_numpy(x.astype(np.float64)).permute(0, 3, 1, 2),
                                      torch.from_numpy(k.astype(np.float64)).permute(3, 2, 0, 1),
                                      padding=dilation, dilation=dilation).permute(0, 2, 3, 1).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * np.abs(want).max())


def test_state_is_donated_off_the_cpu_only():
    assert state_donation("cpu") == () and state_donation("gpu") == (0,) and state_donation("tpu") == (0,)
