"""InfoNCE (off-road Eq. 2) against NumPy and a closed form."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import logsumexp

from jaxanom.offroad.contrastive import info_nce


def unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def numpy_info_nce(z, zp, zn, mask, tau):
    losses = []
    for i in range(len(z)):
        if not mask[i]:
            continue
        pos = np.exp(z[i] @ zp[i] / tau)
        negs = sum(np.exp(z[i] @ zn[i, j] / tau) for j in range(zn.shape[1]))
        losses.append(-np.log(pos / (pos + negs)))
    return np.mean(losses) if losses else 0.0


@pytest.mark.parametrize("q, n, d, tau", [(7, 5, 16, 0.1), (1, 1, 3, 1.0), (12, 16, 8, 0.5)])
def test_matches_numpy_formula(q, n, d, tau):
    rng = np.random.default_rng(q + n)
    z, zp, zn = unit(rng.normal(size=(q, d))), unit(rng.normal(size=(q, d))), unit(rng.normal(size=(q, n, d)))
    mask = rng.random(q) < 0.7
    mask[0] = True
    got = info_nce(z, zp, zn, mask, temperature=tau)
    assert got.dtype == jnp.float32 and got.shape == ()
    np.testing.assert_allclose(got, numpy_info_nce(z, zp, zn, mask, tau), rtol=2e-5)


def test_closed_form_identical_positive_orthogonal_negatives():
    d, n, tau = 8, 5, 0.1
    eye = np.eye(d)
    z = eye[:1]
    zn = eye[1 : n + 1][None]
    expected = -np.log(np.exp(1 / tau) / (np.exp(1 / tau) + n))
    np.testing.assert_allclose(info_nce(z, z, zn, temperature=tau), expected, rtol=1e-5)


def test_stable_at_tiny_temperature_and_huge_values():
    rng = np.random.default_rng(1)
    z, zp, zn = rng.normal(size=(4, 6)) * 30, rng.normal(size=(4, 6)) * 30, rng.normal(size=(4, 3, 6)) * 30
    tau = 0.01
    logits = np.concatenate([np.sum(z * zp, -1)[:, None], np.einsum("qd,qnd->qn", z, zn)], axis=1) / tau
    expected = np.mean(logsumexp(logits, axis=1) - logits[:, 0])
    got = info_nce(z, zp, zn, temperature=tau)
    assert np.isfinite(got)
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_masked_queries_are_ignored_and_empty_mask_gives_zero():
    rng = np.random.default_rng(2)
    z, zp, zn = unit(rng.normal(size=(5, 4))), unit(rng.normal(size=(5, 4))), unit(rng.normal(size=(5, 3, 4)))
    mask = np.array([True, False, True, False, False])
    garbage = z.copy()
    garbage[1] = 1e3  # a masked query's values must not matter
    np.testing.assert_allclose(info_nce(garbage, zp, zn, mask), info_nce(z[[0, 2]], zp[[0, 2]], zn[[0, 2]]), rtol=1e-6)
    assert float(info_nce(z, zp, zn, np.zeros(5, bool))) == 0.0
    assert float(info_nce(z, z, zn[:, :0])) == 0.0  # no negatives: log(1) = 0


def test_gradient_pulls_query_towards_positive_and_works_under_jit():
    rng = np.random.default_rng(3)
    z, zp, zn = unit(rng.normal(size=(6, 5))), unit(rng.normal(size=(6, 5))), unit(rng.normal(size=(6, 4, 5)))
    grad = jax.jit(jax.grad(lambda a: info_nce(a, zp, zn)))(jnp.asarray(z, jnp.float32))
    stepped = z - 0.05 * np.asarray(grad)
    assert (np.sum(stepped * zp, -1) > np.sum(z * zp, -1)).all()
    assert info_nce(stepped, zp, zn) < info_nce(z, zp, zn)


def test_bad_input_raises():
    z = np.zeros((3, 4))
    with pytest.raises(ValueError, match="z_pos must have the shape"):
        info_nce(z, z[:2], np.zeros((3, 2, 4)))
    with pytest.raises(ValueError, match="z_neg must have shape"):
        info_nce(z, z, np.zeros((3, 2, 5)))
    with pytest.raises(ValueError, match="z_neg must have rank 3"):
        info_nce(z, z, np.zeros((3, 4)))
    with pytest.raises(ValueError, match="mask must have shape"):
        info_nce(z, z, np.zeros((3, 2, 4)), np.ones(2, bool))
    with pytest.raises(ValueError, match="temperature must be > 0"):
        info_nce(z, z, np.zeros((3, 2, 4)), temperature=0.0)
    bad = np.zeros((3, 2, 4))
    bad[2, 1, 3] = np.nan
    with pytest.raises(ValueError, match="z_neg must be finite"):
        info_nce(z, z, bad)
