"""Bilinear resize against a NumPy reference (half-pixel centres, clamped borders)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.nn.layers import resize_bilinear


def resize_reference(x, height, width):
    """Pixel by pixel: sample at ((o + 0.5) * n_in / n_out - 0.5), clamped, linear blend."""
    b, h, w, c = x.shape
    out = np.zeros((b, height, width, c))
    for y in range(height):
        sy = min(max((y + 0.5) * h / height - 0.5, 0), h - 1)
        y0, ty = int(sy), sy - int(sy)
        y1 = min(y0 + 1, h - 1)
        for xx in range(width):
            sx = min(max((xx + 0.5) * w / width - 0.5, 0), w - 1)
            x0, tx = int(sx), sx - int(sx)
            x1 = min(x0 + 1, w - 1)
            top = (1 - tx) * x[:, y0, x0] + tx * x[:, y0, x1]
            bottom = (1 - tx) * x[:, y1, x0] + tx * x[:, y1, x1]
            out[:, y, xx] = (1 - ty) * top + ty * bottom
    return out


@pytest.mark.parametrize("src, dst", [((5, 7), (19, 23)), ((4, 4), (16, 16)), ((9, 11), (4, 3)),
                                      ((1, 1), (3, 5)), ((6, 5), (6, 9)), ((3, 3), (3, 3))])
def test_resize_bilinear_matches_reference(src, dst):
    x = np.random.default_rng(0).normal(size=(2, *src, 3)).astype(np.float32)
    got = jax.jit(resize_bilinear, static_argnums=(1, 2))(jnp.asarray(x), *dst)
    assert got.shape == (2, *dst, 3) and got.dtype == jnp.float32
    np.testing.assert_allclose(got, resize_reference(x.astype(np.float64), *dst), rtol=1e-5, atol=1e-6)


def test_resize_bilinear_keeps_bfloat16():
    x = jnp.ones((1, 3, 4, 2), jnp.bfloat16)
    out = resize_bilinear(x, 7, 9)
    assert out.dtype == jnp.bfloat16
    np.testing.assert_array_equal(np.asarray(out, np.float32), 1.0)  # weights sum to 1
