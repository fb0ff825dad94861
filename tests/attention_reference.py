"""NumPy references for the attention modules, written from the papers: bilinear resize (half-pixel
centres, clamped borders), a same-padded convolution, and CuDAM's Eqs. 1-3."""
import jax
import numpy as np


def interp_matrix(n_in, n_out):
    """Linear interpolation with half-pixel centres, clamped at the borders: (n_out, n_in)."""
    m = np.zeros((n_out, n_in))
    for o in range(n_out):
        src = min(max((o + 0.5) * n_in / n_out - 0.5, 0.0), n_in - 1)
        i0 = int(np.floor(src))
        i1 = min(i0 + 1, n_in - 1)
        m[o, i0] += 1 - (src - i0)
        m[o, i1] += src - i0
    return m


def resize(x, h, w):
    """(B, h0, w0, C) -> (B, h, w, C) bilinear."""
    return np.einsum("ih,bhwc,jw->bijc", interp_matrix(x.shape[1], h), x, interp_matrix(x.shape[2], w))


def conv_same(x, kernel, bias):
    """Zero-padded stride-1 cross-correlation: x (B, h, w, Ci), kernel (k, k, Ci, Co)."""
    k = kernel.shape[0]
    p = k // 2
    xp = np.pad(x, ((0, 0), (p, p), (p, p), (0, 0)))
    b, h, w, _ = x.shape
    out = np.zeros((b, h, w, kernel.shape[-1]))
    for dy in range(k):
        for dx in range(k):
            out += np.einsum("bhwc,co->bhwo", xp[:, dy : dy + h, dx : dx + w], kernel[dy, dx])
    return out + bias


def softmax(x, axis):
    e = np.exp(x - x.max(axis=axis, keepdims=True))
    return e / e.sum(axis=axis, keepdims=True)


def sigmoid(x):
    return 1 / (1 + np.exp(-x))


def as_np(tree):
    return jax.tree.map(lambda a: np.asarray(a, np.float64), tree)


def cudam_reference(p, f_a, f_low, f_mid):
    """Eqs. 1-3 as printed: pool, conv, spatial softmax; concat-then-1x1-conv; gated residual."""
    b, h, w, _ = f_a.shape
    pooled = np.stack([f_a.mean(-1), f_a.max(-1)], -1)
    scores = conv_same(pooled, p["attention_conv"]["kernel"], p["attention_conv"]["bias"])[..., 0]
    att = softmax(scores.reshape(b, -1), -1).reshape(b, h, w)
    cat = np.concatenate([resize(f_low, h, w), resize(f_mid, h, w), f_a], -1)
    f_sc = cat @ p["fusion_kernel"] + p["fusion_bias"]
    return p["alpha"] * att[..., None] * (f_a + f_sc) + f_a, att
