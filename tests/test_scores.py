"""Per-pixel scores against float64 NumPy written from their definitions."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from absl.testing import parameterized
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jaxanom import scores


def softmax64(logits):
    z = logits.astype(np.float64)
    e = np.exp(z - z.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def ref_msp(lg):
    return 1.0 - softmax64(lg).max(-1)


def ref_max_logit(lg):
    return -lg.astype(np.float64).max(-1)


def ref_entropy(lg, normalize=False):
    p = softmax64(lg)
    h = -np.sum(np.where(p > 0, p * np.log(np.where(p > 0, p, 1.0)), 0.0), -1)
    return h / np.log(lg.shape[-1]) if normalize else h


def ref_energy(lg, t=1.0):
    z = lg.astype(np.float64) / t
    m = z.max(-1)
    return -t * (m + np.log(np.exp(z - m[..., None]).sum(-1)))


def ref_softmax_distance(lg):  # MMF Eq. 2 with log-free probabilities
    p = np.sort(softmax64(lg), axis=-1)
    return 1.0 - p[..., -1] + p[..., -2]


REFS = {
    "msp": (scores.msp, ref_msp),
    "max_logit": (scores.max_logit, ref_max_logit),
    "entropy": (scores.entropy, ref_entropy),
    "entropy_normalized": (lambda x: scores.entropy(x, normalize=True), lambda x: ref_entropy(x, True)),
    "energy": (scores.energy, ref_energy),
    "energy_t": (lambda x: scores.energy(x, temperature=0.3), lambda x: ref_energy(x, 0.3)),
    "softmax_distance": (scores.softmax_distance, ref_softmax_distance),
}


def logit_cases():
    rng = np.random.default_rng(0)
    yield "random-odd", rng.normal(size=(7, 9, 19)) * 3
    yield "ties", rng.integers(-2, 3, size=(5, 6, 4)).astype(float)  # many tied maxima
    yield "huge", rng.normal(size=(3, 5, 6)) * 1e4
    yield "uniform", np.zeros((2, 3, 5))
    yield "two-classes", rng.normal(size=(4, 4, 2))


CASES = list(logit_cases())


@pytest.mark.parametrize("name", list(REFS))
@pytest.mark.parametrize("case,logits", CASES, ids=[c[0] for c in CASES])
def test_scores_match_numpy(name, case, logits):
    fn, ref_fn = REFS[name]
    logits = logits.astype(np.float32)
    got = fn(logits)
    assert got.shape == logits.shape[:2] and got.dtype == jnp.float32
    scale = 1e4 if case == "huge" and name in ("max_logit", "energy", "energy_t") else 1.0
    np.testing.assert_allclose(np.asarray(got), ref_fn(logits), rtol=1e-5, atol=2e-6 * scale)


def test_msp_keeps_precision_for_confident_pixels():
    logits = np.array([[[30.0, 0.0, 0.0]]], np.float32)  # 1 - p = 2e-13, below float32 eps of 1
    want = 2 * np.exp(-30.0) / (1 + 2 * np.exp(-30.0))
    np.testing.assert_allclose(np.asarray(scores.msp(logits)), [[want]], rtol=1e-5)


def test_single_class():
    logits = np.random.default_rng(1).normal(size=(3, 4, 1)).astype(np.float32)
    np.testing.assert_allclose(np.asarray(scores.msp(logits)), 0.0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(scores.entropy(logits)), 0.0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(scores.energy(logits)), -logits[..., 0], rtol=1e-6)


@settings(max_examples=30, deadline=None)
@given(hnp.arrays(np.float32, (3, 4, 5), elements=st.floats(-30, 30, width=32, allow_subnormal=False)))
def test_bounded_scores_stay_in_range(logits):
    for fn in (scores.msp, lambda x: scores.entropy(x, normalize=True), scores.softmax_distance):
        out = np.asarray(fn(logits))
        assert np.all(out >= -1e-6) and np.all(out <= 1 + 1e-6)


class JitVsEager(chex.TestCase):
    @chex.variants(with_jit=True, without_jit=True)
    @parameterized.parameters(*REFS)
    def test_same_under_jit(self, name):
        fn, ref_fn = REFS[name]
        logits = np.random.default_rng(2).normal(size=(5, 7, 6)).astype(np.float32) * 2
        np.testing.assert_allclose(np.asarray(self.variant(fn)(logits)), ref_fn(logits), rtol=1e-5, atol=2e-6)


BATCHED = {
    "msp": (scores.msp_batch, scores.msp),
    "max_logit": (scores.max_logit_batch, scores.max_logit),
    "entropy": (lambda x: scores.entropy_batch(x, normalize=True), lambda x: scores.entropy(x, normalize=True)),
    "energy": (lambda x: scores.energy_batch(x, 2.0), lambda x: scores.energy(x, 2.0)),
    "softmax_distance": (scores.softmax_distance_batch, scores.softmax_distance),
}


@pytest.mark.parametrize("name", list(BATCHED))
def test_batch_equals_loop_and_vmap(name):
    batched, single = BATCHED[name]
    logits = np.random.default_rng(3).normal(size=(3, 4, 5, 6)).astype(np.float32)
    loop = np.stack([np.asarray(single(lg)) for lg in logits])
    np.testing.assert_allclose(np.asarray(batched(logits)), loop, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.asarray(jax.jit(jax.vmap(single))(jnp.asarray(logits))), loop, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: scores.msp(np.zeros((4, 5))), r"logits must have rank 3 \(H, W, C\), got shape \(4, 5\)"),
        (lambda: scores.max_logit(np.zeros((1, 2, 3, 4))), "logits must have rank 3"),
        (lambda: scores.entropy(np.array([[[0.0, np.nan]]])), "logits must be finite, got 1 NaN/Inf"),
        (lambda: scores.energy(np.array([[[0.0, np.inf]]])), "logits must be finite"),
        (lambda: scores.energy(np.zeros((2, 2, 2)), temperature=0.0), "temperature must be > 0"),
        (lambda: scores.softmax_distance(np.zeros((2, 2, 1))), "logits need C >= 2"),
        (lambda: scores.entropy(np.zeros((2, 2, 1)), normalize=True), "logits need C >= 2"),
        (lambda: scores.msp_batch(np.zeros((2, 2, 2))), r"logits must have rank 4 \(B, H, W, C\)"),
        (lambda: scores.energy_batch(np.zeros((1, 2, 2, 2)), temperature=-1.0), "temperature must be > 0"),
    ],
)
def test_bad_input_raises_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()
