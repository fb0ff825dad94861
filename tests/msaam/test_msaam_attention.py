"""MSAAM's attention module (Eqs. 1-6, 8-12) against NumPy references written from the paper."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.msaam.attention import MSAAMAttention, adaptive_pool_matrix, best_rectangle
from attention_reference import as_np, conv_same, resize, sigmoid, softmax

RNG = np.random.default_rng(0)
KEY = jax.random.key(0, impl="rbg")  # cheap to compile on CPU


def adaptive_pool_reference(x, n):
    """PyTorch adaptive average pooling of (B, h, w) to (B, n, n), cell by cell."""
    b, h, w = x.shape
    out = np.zeros((b, n, n))
    for i in range(n):
        for j in range(n):
            y0, y1 = int(np.floor(i * h / n)), int(np.ceil((i + 1) * h / n))
            x0, x1 = int(np.floor(j * w / n)), int(np.ceil((j + 1) * w / n))
            out[:, i, j] = x[:, y0:y1, x0:x1].mean(axis=(1, 2))
    return out


def dense(p, x):
    return x @ p["kernel"] + p.get("bias", 0.0)


def gru_reference(p, h, x):
    """Standard GRU cell (the reset gate multiplies the hidden projection incl. its bias)."""
    r = sigmoid(dense(p["ir"], x) + dense(p["hr"], h))
    z = sigmoid(dense(p["iz"], x) + dense(p["hz"], h))
    n = np.tanh(dense(p["in"], x) + r * dense(p["hn"], h))
    return (1 - z) * n + z * h


def msaam_reference(p, f, bins, steps):
    b, h, w, c = f.shape
    # Scale branch, Eqs. 1-2: pool F first, then the 1x1 conv (the paper's order).
    total = np.zeros((b, h, w))
    for i, n in enumerate(bins):
        pooled = np.stack([adaptive_pool_reference(f[..., k], n) for k in range(c)], -1)
        level = pooled @ p["scale_convs"]["kernel"][:, i] + p["scale_convs"]["bias"][i]
        total += p["scale_level_weights"][i] * resize(level[..., None], h, w)[..., 0]
    a = softmax(total.reshape(b, -1), -1).reshape(b, h, w)
    f_sc = f + f * a[..., None]
    # Spatial branch, Eq. 3: embedded-Gaussian non-local relation, 7x7 conv, sigmoid.
    theta, phi, g = (dense(p[n], f).reshape(b, h * w, -1) for n in ("theta", "phi", "g"))
    rel = np.exp(np.einsum("bic,bjc->bij", theta, phi))
    y = np.einsum("bij,bjc->bic", rel / rel.sum(-1, keepdims=True), g).reshape(b, h, w, -1)
    m_sp = sigmoid(conv_same(y, p["spatial_conv"]["kernel"], p["spatial_conv"]["bias"])[..., 0])
    f_sp = f * m_sp[..., None]
    # Channel branch, Eq. 4.
    d = f.mean(axis=(1, 2))
    d = np.maximum(d @ p["channel_w1"]["kernel"], 0)
    d = np.maximum(d @ p["channel_w2"]["kernel"], 0)
    f_c = f * sigmoid(dense(p["channel_w3"], d))[:, None, None, :]
    # Fusion, Eqs. 5-6.
    x = sum(f_b.mean(axis=(1, 2)) @ p[f"gru_in_{n}"]["kernel"]
            for n, f_b in zip(("scale", "spatial", "channel"), (f_sc, f_sp, f_c)))
    state = np.zeros((b, p["gru"]["hr"]["kernel"].shape[0]))
    for _ in range(steps):
        state = gru_reference(p["gru"], state, x)
    alpha = softmax(dense(p["branch_logits"], state), -1)
    out = sum(alpha[:, i, None, None, None] * f_b for i, f_b in enumerate((f_sc, f_sp, f_c)))
    # Highlight maps, Eqs. 8-11 (channel means).
    sc = alpha[:, 0, None, None] * f_sc.mean(-1)
    sp = alpha[:, 1, None, None] * m_sp
    ch = alpha[:, 2, None, None] * f_c.mean(-1)
    co = alpha[:, 0, None, None] * sc + alpha[:, 1, None, None] * sp + alpha[:, 2, None, None] * ch
    return out, {"attention": a, "branch_weights": alpha, "highlight_scale": sc,
                 "highlight_spatial": sp, "highlight_channel": ch, "highlight_combined": co}


@pytest.mark.parametrize("size", [(5, 7), (1, 1)])
def test_adaptive_pool_matrix_matches_cellwise_pooling(size):
    x = RNG.normal(size=(1, *size))
    for n in (1, 2, 3, 6):
        got = adaptive_pool_matrix(size[0], n) @ x[0] @ adaptive_pool_matrix(size[1], n).T
        np.testing.assert_allclose(got, adaptive_pool_reference(x, n)[0], rtol=1e-6)


def test_msaam_matches_numpy_reference():
    # h = 5 < 6 bins: the finest pyramid level has overlapping cells
    f = RNG.normal(size=(2, 5, 7, 16)).astype(np.float32)
    module = MSAAMAttention(reduction=8, channel_reduction=4, gru_features=8, gru_steps=2)
    params = jax.jit(module.init)(KEY, f)["params"]
    # sharpen the scale scores and the branch logits so maps and weights are far from uniform
    params["scale_convs"] = {**params["scale_convs"], "kernel": params["scale_convs"]["kernel"] * 4}
    params["branch_logits"] = {**params["branch_logits"], "kernel": params["branch_logits"]["kernel"] * 8}
    features, outputs = jax.jit(module.apply)({"params": params}, f)
    want_f, want = msaam_reference(as_np(params), f.astype(np.float64), module.bins, module.gru_steps)
    np.testing.assert_allclose(features, want_f, rtol=1e-4, atol=1e-5)
    assert set(outputs) == set(want)
    for name, value in want.items():
        np.testing.assert_allclose(outputs[name], value, rtol=1e-4, atol=1e-6, err_msg=name)
    np.testing.assert_allclose(np.asarray(outputs["attention"]).sum((1, 2)), 1.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(outputs["branch_weights"]).sum(1), 1.0, rtol=1e-6)
    assert np.ptp(want["branch_weights"]) > 0.05 and np.ptp(want["attention"]) > 1e-3


# ----------------------------------------------------------------------------- Eq. 12
def best_rectangle_reference(m, bh, bw):
    best, corner = -np.inf, None
    for y in range(m.shape[0] - bh + 1):
        for x in range(m.shape[1] - bw + 1):
            avg = m[y : y + bh, x : x + bw].sum() / (bh * bw)
            if avg > best + 1e-9:  # first best in row-major order
                best, corner = avg, (y, x, y + bh - 1, x + bw - 1)
    return corner, best


@pytest.mark.parametrize("box", [(1, 1), (2, 3), (5, 7), (3, 1)])
def test_best_rectangle_matches_brute_force(box):
    m = RNG.integers(0, 4, size=(5, 7)).astype(np.float32)  # small integers: many ties
    corner, avg = best_rectangle(jnp.asarray(m), *box)
    want_corner, want_avg = best_rectangle_reference(m, *box)
    assert tuple(np.asarray(corner)) == want_corner
    np.testing.assert_allclose(avg, want_avg, rtol=1e-6)


@pytest.mark.parametrize("shape, box", [((5, 7), (6, 1)), ((5, 7), (1, 0)), ((2, 5, 7), (1, 1))])
def test_best_rectangle_rejects_bad_sizes(shape, box):
    with pytest.raises(ValueError, match="height|highlight"):
        best_rectangle(jnp.zeros(shape), *box)
