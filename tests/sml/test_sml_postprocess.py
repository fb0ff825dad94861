"""Boundary suppression and dilated smoothing against explicit NumPy/SciPy references."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from absl.testing import parameterized
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import sml_reference as ref
from jaxanom import sml


def cases():
    rng = np.random.default_rng(1)
    yield "random-odd", rng.integers(0, 4, (11, 13))
    yield "blocks", np.kron(rng.integers(0, 19, (3, 4)), np.ones((5, 4), int))[:14, :15]
    stripes = np.zeros((12, 9), int)
    stripes[5, :] = 3
    stripes[:, 2] = 6
    yield "one-pixel-wide", stripes
    yield "single-class", np.full((7, 9), 4)
    yield "checkerboard", np.indices((6, 7)).sum(0) % 2
    yield "two-halves", (np.arange(16) >= 7)[None, :].repeat(15, 0)  # distances up to 8: every radius shows


CASES = list(cases())
DEFAULTS = [(4, 4, "geodesic"), (4, 4, "sml_official")]
OTHER_SETTINGS = [(4, 2, "geodesic"), (6, 3, "sml_official"), (0, 2, "geodesic"), (3, 1, "geodesic")]
# every map with the paper's settings in both border modes; the other settings on the first and
# last maps (on the first, a band of radius >= 2 already covers every pixel)
SUPPRESSION_CASES = [(name, label, *setting) for name, label in CASES for setting in DEFAULTS]
SUPPRESSION_CASES += [(*case, *setting) for case in (CASES[0], CASES[-1]) for setting in OTHER_SETTINGS]


@pytest.mark.parametrize("name,label,width,iterations,border", SUPPRESSION_CASES,
                         ids=[f"{c[0]}-{c[2]}-{c[3]}-{c[4]}" for c in SUPPRESSION_CASES])
def test_suppression_matches_python_loop(name, label, width, iterations, border):
    score = np.random.default_rng(len(name)).normal(size=label.shape).astype(np.float32) * 3
    got = sml.suppress_boundaries(score, label.astype(np.int32), width=width, iterations=iterations, border=border)
    want = ref.suppress(score, label, width, iterations, border)
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5, atol=1e-5)


SMOOTHING_CASES = [((9, 14), 7, 1.0, 6), ((40, 37), 7, 1.0, 6), ((1, 5), 7, 1.0, 6),
                   ((9, 14), 5, 0.7, 1), ((9, 14), 3, 2.0, 2), ((9, 14), 1, 1.0, 4)]


@pytest.mark.parametrize("shape,kernel_size,sigma,dilation", SMOOTHING_CASES)
def test_smoothing_matches_scipy_correlate(shape, kernel_size, sigma, dilation):
    score = np.random.default_rng(2).normal(size=shape).astype(np.float32) * 5
    got = sml.dilated_smoothing(score, kernel_size=kernel_size, sigma=sigma, dilation=dilation)
    np.testing.assert_allclose(np.asarray(got), ref.smooth(score, kernel_size, sigma, dilation), rtol=1e-5, atol=1e-5)


def test_huge_scores_keep_relative_precision():
    label = np.random.default_rng(3).integers(0, 3, (10, 12))
    score = np.random.default_rng(4).normal(size=label.shape).astype(np.float32) * 1e30
    got = sml.postprocess(score, label)
    np.testing.assert_allclose(np.asarray(got), ref.smooth(ref.suppress(score, label)), rtol=1e-5, atol=1e25)


LABELS = hnp.arrays(np.int32, (9, 10), elements=st.integers(0, 3))
SCORES = hnp.arrays(np.float32, (9, 10), elements=st.floats(-100, 100, width=32, allow_subnormal=False))


@settings(max_examples=30, deadline=None)
@given(label=LABELS, score=SCORES, border=st.sampled_from(sml.BORDERS))
def test_suppression_never_changes_non_boundary_pixels(label, score, border):
    out = np.asarray(sml.suppress_boundaries(score, label, border=border))
    outside = ~ref.expand(ref.boundaries(label, border), 3)  # widest band: radius width - 1
    np.testing.assert_array_equal(out[outside], score[outside])


@settings(max_examples=20, deadline=None)
@given(value=st.floats(-1e6, 1e6, width=32, allow_subnormal=False), shape=st.sampled_from([(5, 8), (12, 7)]))
def test_smoothing_a_constant_returns_it(value, shape):
    out = np.asarray(sml.dilated_smoothing(np.full(shape, value, np.float32)))
    np.testing.assert_allclose(out, value, rtol=2e-6, atol=1e-30)


class JitVsEager(chex.TestCase):
    @chex.variants(with_jit=True, without_jit=True)
    @parameterized.parameters("geodesic", "sml_official")
    def test_postprocess_same_under_jit(self, border):
        label = np.random.default_rng(5).integers(0, 4, (11, 13)).astype(np.int32)
        score = np.random.default_rng(6).normal(size=label.shape).astype(np.float32)
        fn = self.variant(lambda s, p: sml.postprocess(s, p, border=border))
        want = ref.smooth(ref.suppress(score, label, border=border))
        np.testing.assert_allclose(np.asarray(fn(score, label)), want, rtol=1e-5, atol=1e-5)


def test_postprocess_batch_equals_loop_and_vmap():
    labels = np.random.default_rng(7).integers(0, 5, (3, 10, 11)).astype(np.int32)
    scores = np.random.default_rng(8).normal(size=labels.shape).astype(np.float32)
    batch = np.asarray(sml.postprocess_batch(scores, labels, width=2, iterations=2))
    loop = np.stack([np.asarray(sml.postprocess(s, p, width=2, iterations=2)) for s, p in zip(scores, labels)])
    vmapped = jax.vmap(lambda s, p: sml.suppress_boundaries(s, p, width=2, iterations=2))(jnp.asarray(scores), jnp.asarray(labels))
    np.testing.assert_allclose(batch, loop, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(vmapped), np.stack([ref.suppress(s, p, 2, 2) for s, p in zip(scores, labels)]), rtol=1e-5, atol=1e-5)


def test_both_steps_off_returns_the_score():
    score = np.random.default_rng(9).normal(size=(6, 7)).astype(np.float32)
    out = sml.postprocess(score, np.zeros((6, 7), np.int32), suppress=False, smooth=False)
    np.testing.assert_array_equal(np.asarray(out), score)


GOOD_SCORE, GOOD_PRED = np.zeros((4, 5), np.float32), np.zeros((4, 5), np.int32)


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: sml.suppress_boundaries(GOOD_SCORE, GOOD_PRED, width=4, iterations=3), "width must be a multiple of iterations"),
        (lambda: sml.suppress_boundaries(GOOD_SCORE, GOOD_PRED, iterations=0), "iterations must be an int >= 1"),
        (lambda: sml.suppress_boundaries(GOOD_SCORE, GOOD_PRED, width=-2, iterations=2), "width must be an int >= 0"),
        (lambda: sml.suppress_boundaries(GOOD_SCORE, GOOD_PRED, border="zeros"), "border must be one of"),
        (lambda: sml.suppress_boundaries(GOOD_SCORE[None], GOOD_PRED), "score must have rank 2"),
        (lambda: sml.suppress_boundaries(GOOD_SCORE, GOOD_PRED[:3]), r"prediction must have the score's shape \(4, 5\)"),
        (lambda: sml.suppress_boundaries(GOOD_SCORE, GOOD_SCORE), "prediction must hold integer"),
        (lambda: sml.suppress_boundaries(np.full((4, 5), np.nan, np.float32), GOOD_PRED), "score must be finite"),
        (lambda: sml.dilated_smoothing(GOOD_SCORE, kernel_size=6), "kernel_size must be an odd int"),
        (lambda: sml.dilated_smoothing(GOOD_SCORE, sigma=0.0), "sigma must be > 0"),
        (lambda: sml.dilated_smoothing(GOOD_SCORE, dilation=0), "dilation must be an int >= 1"),
        (lambda: sml.dilated_smoothing(np.array([1.0, np.inf], np.float32)[None]), "score must be finite"),
        (lambda: sml.postprocess_batch(GOOD_SCORE, GOOD_PRED), "score must have rank 3"),
    ],
)
def test_bad_input_raises_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()
