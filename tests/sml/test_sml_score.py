"""standardized_max_logit and sml_score against the NumPy reference pipeline."""
import chex
import jax.numpy as jnp
import numpy as np
import pytest
from absl.testing import parameterized

import sml_reference as ref
from jaxanom import sml


def problem(seed, shape=(11, 14), num_classes=5):
    rng = np.random.default_rng(seed)
    coarse = rng.normal(size=(3, 4, num_classes)) * 3  # smooth-ish logits: regions, not noise
    logits = np.kron(coarse, np.ones((4, 4, 1)))[: shape[0], : shape[1]] + rng.normal(size=shape + (num_classes,))
    mean = rng.normal(size=num_classes) * 2
    std = 0.5 + rng.random(num_classes)
    return logits.astype(np.float32), mean.astype(np.float32), std.astype(np.float32)


def test_standardized_max_logit_matches_eq5():
    logits, mean, std = problem(0)
    got, pred = sml.standardized_max_logit(logits, mean, std)
    want, want_pred = ref.standardize(logits, mean.astype(np.float64), std.astype(np.float64))
    np.testing.assert_array_equal(np.asarray(pred), want_pred)
    assert pred.dtype == jnp.int32 and got.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5, atol=1e-6)


def test_ties_take_the_first_class():
    logits = np.zeros((2, 3, 4), np.float32)
    logits[..., 1:3] = 5.0  # classes 1 and 2 tie
    _, pred = sml.standardized_max_logit(logits, np.zeros(4, np.float32), np.ones(4, np.float32))
    np.testing.assert_array_equal(np.asarray(pred), 1)


@pytest.mark.parametrize(
    "suppress,smooth,border",
    [(True, True, "geodesic"), (True, True, "sml_official"), (True, False, "geodesic"), (False, True, "geodesic"), (False, False, "geodesic")],
)
def test_sml_score_matches_reference_pipeline(suppress, smooth, border):
    logits, mean, std = problem(1)
    s, pred = ref.standardize(logits, mean.astype(np.float64), std.astype(np.float64))
    if suppress:
        s = ref.suppress(s, pred, 4, 4, border)
    if smooth:
        s = ref.smooth(s)
    got = sml.sml_score(logits, mean, std, suppress=suppress, smooth=smooth, border=border)
    np.testing.assert_allclose(np.asarray(got), -s, rtol=1e-5, atol=1e-5)


def test_sml_score_passes_every_option_through():
    rng = np.random.default_rng(7)
    coarse = rng.normal(size=(2, 2, 5))
    coarse[[0, 0, 1, 1], [0, 1, 0, 1], [0, 1, 2, 3]] += 10  # four 8x8 regions: bands of every radius differ
    logits = (np.kron(coarse, np.ones((8, 8, 1))) + rng.normal(size=(16, 16, 5)) * 0.3).astype(np.float32)
    mean, std = rng.normal(size=5).astype(np.float32), (0.5 + rng.random(5)).astype(np.float32)
    s, pred = ref.standardize(logits, mean.astype(np.float64), std.astype(np.float64))
    options = dict(width=2, iterations=2, border="sml_official", kernel_size=5, sigma=2.0, dilation=2)
    want = ref.smooth(ref.suppress(s, pred, 2, 2, "sml_official"), 5, 2.0, 2)
    got = sml.sml_score(logits, mean, std, **options)
    np.testing.assert_allclose(np.asarray(got), -want, rtol=1e-5, atol=1e-5)
    batch = sml.sml_score_batch(logits[None], mean, std, **options)
    np.testing.assert_allclose(np.asarray(batch[0]), -want, rtol=1e-5, atol=1e-5)
    # each option matters here: the defaults' reference is far from this one
    for default in (ref.suppress(s, pred, 4, 2, "sml_official"), ref.suppress(s, pred, 2, 2, "geodesic")):
        assert np.abs(ref.smooth(default, 5, 2.0, 2) - want).max() > 1e-3
    assert np.abs(ref.smooth(ref.suppress(s, pred, 2, 2, "sml_official")) - want).max() > 1e-3


def test_single_class_logits():
    logits = np.random.default_rng(2).normal(size=(6, 5, 1)).astype(np.float32)
    got = sml.sml_score(logits, np.array([0.5], np.float32), np.array([2.0], np.float32))
    want = ref.smooth((logits[..., 0].astype(np.float64) - 0.5) / 2.0)  # no boundaries at all
    np.testing.assert_allclose(np.asarray(got), -want, rtol=1e-5, atol=1e-6)


class JitVsEager(chex.TestCase):
    @chex.variants(with_jit=True, without_jit=True)
    @parameterized.parameters(True, False)
    def test_sml_score_same_under_jit(self, smooth):
        logits, mean, std = problem(3)
        fn = self.variant(lambda lg, m, s: sml.sml_score(lg, m, s, smooth=smooth, width=2, iterations=1))
        s, pred = ref.standardize(logits, mean.astype(np.float64), std.astype(np.float64))
        s = ref.suppress(s, pred, 2, 1)
        want = -(ref.smooth(s) if smooth else s)
        np.testing.assert_allclose(np.asarray(fn(logits, mean, std)), want, rtol=1e-5, atol=1e-5)


def test_batch_equals_loop():
    problems = [problem(seed, (9, 10)) for seed in (4, 5, 6)]
    logits = np.stack([p[0] for p in problems])
    mean, std = problems[0][1], problems[0][2]
    batch = np.asarray(sml.sml_score_batch(logits, mean, std, border="sml_official"))
    loop = np.stack([np.asarray(sml.sml_score(lg, mean, std, border="sml_official")) for lg in logits])
    np.testing.assert_allclose(batch, loop, rtol=1e-6, atol=1e-6)


LOGITS, MEAN, STD = problem(7, (4, 5), 3)


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: sml.sml_score(LOGITS[0], MEAN, STD), r"logits must have rank 3 \(H, W, C\)"),
        (lambda: sml.sml_score(LOGITS, MEAN[:2], STD), r"mean must have shape \(C,\) = \(3,\)"),
        (lambda: sml.sml_score(LOGITS, MEAN, STD[:2]), r"std must have shape \(C,\) = \(3,\)"),
        (lambda: sml.sml_score(LOGITS, MEAN, np.array([1.0, 0.0, 1.0])), "std must be finite and > 0"),
        (lambda: sml.sml_score(LOGITS, MEAN, np.array([1.0, -2.0, 1.0])), "std must be finite and > 0"),
        (lambda: sml.sml_score(LOGITS, MEAN, np.array([1.0, np.nan, 1.0])), "std must be finite and > 0"),
        (lambda: sml.sml_score(LOGITS, np.array([0.0, np.inf, 0.0]), STD), "mean must be finite"),
        (lambda: sml.sml_score(np.where(LOGITS > 0, np.nan, LOGITS), MEAN, STD), "logits must be finite"),
        (lambda: sml.sml_score(np.full_like(LOGITS, np.inf), MEAN, STD), "logits must be finite"),
        (lambda: sml.sml_score(LOGITS, MEAN, STD, width=4, iterations=3), "width must be a multiple of iterations"),
        (lambda: sml.sml_score(LOGITS, MEAN, STD, border="reflect"), "border must be one of"),
        (lambda: sml.sml_score_batch(LOGITS, MEAN, STD), r"logits must have rank 4 \(B, H, W, C\)"),
        (lambda: sml.standardized_max_logit(LOGITS[..., :2], MEAN, STD), r"mean must have shape \(C,\) = \(2,\)"),
    ],
)
def test_bad_input_raises_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()
