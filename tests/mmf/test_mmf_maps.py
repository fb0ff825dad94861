"""MMF Eqs. 1-4 maps and class-mean resynthesis against NumPy written from the equations."""
import jax
import numpy as np
import pytest

from jaxanom.mmf.perceptual import (anomaly_map, anomaly_map_batch, perceptual_difference,
                                    perceptual_difference_batch)
from jaxanom.mmf.synthesis import ClassMeanSynthesizer
from jaxanom.mmf.uncertainty import uncertainty_maps, uncertainty_maps_batch


def softmax64(logits):
    z = logits.astype(np.float64)
    e = np.exp(z - z.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def ref_minmax(x):
    return (x - x.min()) / (x.max() - x.min()) if x.max() > x.min() else np.zeros_like(x)


def ref_bilinear(x, out_hw):
    """Half-pixel-centre bilinear with edge clamping, one axis at a time."""
    for axis, size in enumerate(out_hw):
        n = x.shape[axis]
        src = np.clip((np.arange(size) + 0.5) * n / size - 0.5, 0, n - 1)
        low = np.floor(src).astype(int)
        high = np.minimum(low + 1, n - 1)
        frac = (src - low).reshape([-1 if a == axis else 1 for a in range(x.ndim)])
        x = np.take(x, low, axis) * (1 - frac) + np.take(x, high, axis) * frac
    return x


LOGIT_CASES = {
    "random-odd": np.random.default_rng(0).normal(size=(7, 9, 19)) * 3,
    "ties": np.random.default_rng(1).integers(-2, 3, size=(5, 6, 4)).astype(float),
    "huge": np.random.default_rng(2).normal(size=(3, 5, 6)) * 1e4,
    "two-classes": np.random.default_rng(3).normal(size=(4, 4, 2)),
}


@pytest.mark.parametrize("normalize", ["max", "minmax"])
@pytest.mark.parametrize("case", list(LOGIT_CASES))
def test_uncertainty_maps_match_numpy(case, normalize):
    logits = LOGIT_CASES[case].astype(np.float32)
    p = softmax64(logits)
    bits = -np.sum(np.where(p > 0, p * np.log2(np.where(p > 0, p, 1.0)), 0.0), -1)  # Eq. 1
    top = np.sort(p, -1)
    distance = 1 - top[..., -1] + top[..., -2]  # Eq. 2
    if normalize == "max":
        entropy = bits / np.log2(logits.shape[-1])
    else:
        entropy, distance = ref_minmax(bits), ref_minmax(distance)
    got = uncertainty_maps(logits, road=1, normalize=normalize)
    atol = 1e-3 if normalize == "minmax" and case == "huge" else 2e-5  # min-max magnifies float32 rounding
    np.testing.assert_allclose(np.asarray(got["entropy"]), entropy, atol=atol)
    np.testing.assert_allclose(np.asarray(got["distance"]), distance, atol=atol)
    np.testing.assert_allclose(np.asarray(got["road"]), p[..., 1], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(got["prediction"]), np.argmax(logits, -1))
    for name in ("entropy", "distance", "road"):
        assert np.asarray(got[name]).min() >= 0 and np.asarray(got[name]).max() <= 1 + 1e-6


def test_uncertainty_batch_matches_single():
    logits = np.random.default_rng(4).normal(size=(3, 6, 7, 5)).astype(np.float32)
    batch = uncertainty_maps_batch(logits, normalize="minmax")
    for b in range(3):
        single = uncertainty_maps(logits[b], normalize="minmax")
        for name in single:
            np.testing.assert_allclose(np.asarray(batch[name][b]), np.asarray(single[name]), atol=1e-6)


def ref_perceptual(feats_x, feats_r, out_hw, weights, reduction):
    total = np.zeros(out_hw)
    for fx, fr, w in zip(feats_x, feats_r, weights):
        diff = np.abs(fx.astype(np.float64) - fr)
        total += w * ref_bilinear(diff.sum(-1) if reduction == "sum" else diff.mean(-1), out_hw)
    return ref_minmax(total)


def feature_pair(rng, shapes, batch=None):
    lead = () if batch is None else (batch,)
    fx = [rng.normal(size=lead + s).astype(np.float32) for s in shapes]
    return fx, [f + rng.normal(size=f.shape).astype(np.float32) * rng.random() for f in fx]


SHAPES = [(12, 16, 3), (6, 8, 5), (3, 4, 7), (2, 2, 2)]


@pytest.mark.parametrize("out_hw,weights,reduction", [
    ((12, 16), None, "sum"), ((24, 32), (1 / 32, 1 / 16, 1 / 8, 1 / 4), "mean"), ((9, 13), (2.0, 0.0, 1.0, 0.5), "sum"),
])
def test_perceptual_difference_matches_numpy(out_hw, weights, reduction):
    fx, fr = feature_pair(np.random.default_rng(5), SHAPES)
    got = np.asarray(perceptual_difference(fx, fr, out_hw, weights=weights, reduction=reduction))
    expected = ref_perceptual(fx, fr, out_hw, weights or (1,) * 4, reduction)
    np.testing.assert_allclose(got, expected, atol=2e-5)
    assert got.shape == out_hw and got.dtype == np.float32


def test_perceptual_hand_example_2x2():
    # one layer, 2 channels: |dF| summed over channels = [[1, 3], [0, 2]] -> min-max [[1/3, 1], [0, 2/3]]
    fx = np.array([[[1.0, 0.0], [2.0, 1.0]], [[0.0, 0.0], [1.0, 1.0]]])
    fr = np.array([[[0.0, 0.0], [0.0, 2.0]], [[0.0, 0.0], [0.0, 0.0]]])
    got = np.asarray(perceptual_difference([fx], [fr], (2, 2)))
    np.testing.assert_allclose(got, [[1 / 3, 1.0], [0.0, 2 / 3]], atol=1e-6)


def test_identical_inputs_give_zero_without_nan():
    fx, _ = feature_pair(np.random.default_rng(6), SHAPES)
    got = np.asarray(perceptual_difference(fx, fx, (12, 16)))
    assert not np.isnan(got).any() and (got == 0).all()


def test_perceptual_batch_matches_single():
    fx, fr = feature_pair(np.random.default_rng(7), SHAPES, batch=2)
    batch = np.asarray(perceptual_difference_batch(fx, fr, (12, 16)))
    for b in range(2):
        single = perceptual_difference([f[b] for f in fx], [f[b] for f in fr], (12, 16))
        np.testing.assert_allclose(batch[b], np.asarray(single), atol=1e-6)


def test_anomaly_map_is_resized_entropy_times_perceptual():
    rng = np.random.default_rng(8)
    entropy, perceptual = rng.random((5, 7)).astype(np.float32), rng.random((10, 14)).astype(np.float32)
    entropy[0] = 0.0
    got = np.asarray(anomaly_map(entropy, perceptual))
    np.testing.assert_allclose(got, ref_bilinear(entropy.astype(np.float64), (10, 14)) * perceptual, atol=1e-6)
    assert (got[0] == 0).all()  # U = 0 on the top rows (the first resized row samples row 0 only)
    batch = np.asarray(anomaly_map_batch(entropy[None], perceptual[None]))
    np.testing.assert_allclose(batch[0], got, atol=1e-7)


def test_maps_inside_the_callers_jit():
    fx, fr = feature_pair(np.random.default_rng(9), SHAPES[:2])
    wrapped = jax.jit(lambda a: perceptual_difference([a, fx[1]], fr, (12, 16)))
    np.testing.assert_allclose(np.asarray(wrapped(fx[0])), np.asarray(perceptual_difference(fx, fr, (12, 16))), atol=1e-6)


@pytest.mark.parametrize("seen", [[0, 1, 3, 255], [0, 1]])  # with unknown pixels; without, the last classes unseen
def test_class_mean_synthesizer_fit_and_gather(seen):
    rng = np.random.default_rng(10)
    frames = [{"image": rng.integers(0, 256, (6, 7, 3), dtype=np.uint8),
               "semantic": rng.choice(seen, (6, 7)).astype(np.uint8)} for _ in range(3)]
    synthesizer = ClassMeanSynthesizer.fit(frames, num_classes=4)
    images = np.concatenate([f["image"].reshape(-1, 3) for f in frames]) / 255.0
    classes = np.concatenate([f["semantic"].ravel() for f in frames])
    expected = np.array([images[classes == c].mean(0) if (classes == c).any() else images.mean(0)
                         for c in range(4)] + [images.mean(0)])
    np.testing.assert_allclose(synthesizer.means, expected, atol=1e-6)  # class 2 unseen: the global mean
    semantic = np.array([[0, 1, 2], [3, 255, 0]])
    np.testing.assert_allclose(np.asarray(synthesizer.synthesize(semantic)), expected[[[0, 1, 2], [3, 4, 0]]], atol=1e-6)
    batch = np.asarray(synthesizer.synthesize_batch(np.stack([semantic, semantic[::-1]])))
    np.testing.assert_allclose(batch[1], expected[[[3, 4, 0], [0, 1, 2]]], atol=1e-6)


@pytest.mark.parametrize("call,message", [
    (lambda: uncertainty_maps(np.zeros((4, 4))), "logits must have rank 3"),
    (lambda: uncertainty_maps(np.zeros((4, 4, 1))), "C >= 2"),
    (lambda: uncertainty_maps(np.zeros((4, 4, 3)), road=3), "road must be a class index"),
    (lambda: uncertainty_maps(np.zeros((4, 4, 3)), normalize="log"), "normalize must be one of"),
    (lambda: uncertainty_maps(np.full((4, 4, 3), np.nan)), "logits must be finite"),
    (lambda: uncertainty_maps_batch(np.zeros((4, 4, 3))), "logits must have rank 4"),
    (lambda: perceptual_difference([np.zeros((2, 2, 1))], [np.zeros((2, 3, 1))], (4, 4)), r"feats_r\[0\] must have the shape"),
    (lambda: perceptual_difference([np.zeros((2, 2, 1))], [], (4, 4)), "equally long non-empty lists"),
    (lambda: perceptual_difference([np.zeros((2, 2))], [np.zeros((2, 2))], (4, 4)), r"feats_x\[0\] must have rank 3"),
    (lambda: perceptual_difference([np.zeros((2, 2, 1))], [np.full((2, 2, 1), np.nan)], (4, 4)), r"feats_r\[0\] must be finite"),
    (lambda: perceptual_difference([np.zeros((2, 2, 1))], [np.zeros((2, 2, 1))], (4, 4), weights=(1, 2)), "weights must have one entry"),
    (lambda: perceptual_difference([np.zeros((2, 2, 1))], [np.zeros((2, 2, 1))], (4, 4), reduction="max"), "reduction must be one of"),
    (lambda: perceptual_difference([np.zeros((2, 2, 1))], [np.zeros((2, 2, 1))], (0, 4)), "out_hw must be"),
    (lambda: anomaly_map(np.zeros((2, 2, 1)), np.zeros((2, 2))), "entropy must have rank 2"),
    (lambda: anomaly_map(np.zeros((2, 2)), np.full((2, 2), np.nan)), "perceptual must be finite"),
    (lambda: ClassMeanSynthesizer(np.zeros((3, 3), np.float32)).synthesize(np.full((2, 2), 2)), "semantic must hold classes"),
    (lambda: ClassMeanSynthesizer(np.zeros((3, 3), np.float32)).synthesize(np.array([[0, 1], [255, 2]])),
     r"semantic must hold classes in \[0, 2\) or 255, got \[2\]"),  # one bad value among good ones
    (lambda: ClassMeanSynthesizer(np.zeros((3, 3), np.float32)).synthesize(np.zeros((2, 2), np.float32)), "semantic must hold integer"),
    (lambda: ClassMeanSynthesizer.fit([{"image": np.zeros((2, 2, 3), np.uint8), "semantic": np.full((2, 2), 7)}], 4),
     "must hold classes in"),
])
def test_bad_input_raises(call, message):
    with pytest.raises(ValueError, match=message):
        call()
