"""What the loss tests share: random batches and NumPy references of the cross-entropy (tests/test_losses.py,
tests/cudam/, tests/msaam/)."""
import jax
import numpy as np
import pytest

VOID = 255


def variants(fn):
    """The function eagerly and under jit (shape arguments stay static via closure)."""
    return pytest.mark.parametrize("run", [lambda f, *a: f(*a), lambda f, *a: jax.jit(f)(*a)], ids=["eager", "jit"])(fn)


def random_batch(seed, b=2, h=5, w=7, c=4, void=0.2, scale=3.0):
    rng = np.random.default_rng(seed)
    logits = (scale * rng.normal(size=(b, h, w, c))).astype(np.float32)
    labels = rng.integers(0, c, size=(b, h, w)).astype(np.int32)
    labels[rng.random((b, h, w)) < void] = VOID
    z = rng.normal(size=(b, h * w))
    attention = (np.exp(z) / np.exp(z).sum(1, keepdims=True)).reshape(b, h, w).astype(np.float32)
    score = rng.normal(size=(b, h, w)).astype(np.float32)
    return logits, labels, attention, score


def ref_log_softmax(x):
    x = x.astype(np.float64)
    shifted = x - x.max(-1, keepdims=True)
    return shifted - np.log(np.exp(shifted).sum(-1, keepdims=True))


def ref_cross_entropy(logits, labels, weights=None):
    log_p = ref_log_softmax(logits)
    num, den = 0.0, 0.0
    for idx in np.ndindex(labels.shape):
        y = labels[idx]
        if y == VOID:
            continue
        wy = 1.0 if weights is None else weights[y]
        num += -wy * log_p[idx][y]
        den += wy
    return num / den if den > 0 else 0.0


def ref_correct(logits, labels):
    return (labels != VOID) & (np.argmax(logits, -1) == labels)
