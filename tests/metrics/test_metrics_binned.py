"""binned_anomaly_metrics and sorted_anomaly_metrics: pure JAX AP / AUROC / FPR, within their stated
bound of the exact host metrics."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_metrics_smiyc_convention import real_frames

from jaxanom.errors import InputError
from jaxanom.metrics import anomaly_metrics, binned_anomaly_metrics, score_histogram, sorted_anomaly_metrics

METRICS = (("ap", "ap_error_bound"), ("auroc", "auroc_error_bound"), ("fpr_at_tpr", "fpr_error_bound"))
SLACK = 1e-9  # the host's own float64 rounding over up to ~10^6 curve points


def assert_within_bound(got, scores, labels, **settings):
    exact = anomaly_metrics(scores, labels, **settings)
    for metric, bound in METRICS:
        error = abs(float(got[metric]) - exact[metric])
        assert error <= float(got[bound]) + SLACK, (metric, error, float(got[bound]), settings)
    assert int(got["num_positives"]) == exact["num_positives"]
    assert int(got["num_negatives"]) == exact["num_negatives"]
    return exact


def random_maps(seed, count, shape=(24, 40), levels=None):
    rng = np.random.default_rng(seed)
    labels = (rng.random((count, *shape)) < 0.2).astype(np.uint8)
    labels[rng.random(labels.shape) < 0.1] = 255
    scores = rng.normal(size=labels.shape) + labels
    if levels:  # many ties
        scores = np.round(scores * levels) / levels
    return scores.astype(np.float32), labels


@pytest.mark.parametrize("levels", [None, 4])
def test_random_maps_within_the_bound_under_jit_and_vmap(levels):
    scores, labels = random_maps(0, 4, levels=levels)
    for fpr_convention, ap_convention, num_bins in (("first", "step", 64), ("interp", "trapz", 7),
                                                    ("strict", "envelope", 1000)):
        settings = dict(fpr_convention=fpr_convention, ap_convention=ap_convention)
        got = jax.jit(jax.vmap(lambda s, l: binned_anomaly_metrics(s, l, num_bins=num_bins, tpr=0.9, **settings)))(
            scores, labels)
        for i in range(len(scores)):
            assert_within_bound({k: v[i] for k, v in got.items()}, scores[i], labels[i], tpr=0.9, **settings)
    if levels is None:  # the bounds are small, not vacuous
        assert float(got["auroc_error_bound"].max()) < 2e-3 and float(got["ap_error_bound"].max()) < 0.05


def test_a_coarse_histogram_differs_from_the_exact_numbers_yet_stays_within_the_bound():
    scores, labels = random_maps(1, 1)
    got = binned_anomaly_metrics(scores[0], labels[0], num_bins=5)
    exact = assert_within_bound(got, scores[0], labels[0])
    assert all(float(got[m]) != exact[m] for m, _ in METRICS)


def test_one_positive_ties_and_a_given_range():
    labels = np.zeros((10, 10), np.uint8)
    labels[3, 4] = 1
    scores = np.tile(np.linspace(0, 1, 10, dtype=np.float32), (10, 1))  # ten scores, ten pixels each
    for score_range in (None, (0.0, 1.0), (-5.0, 5.0), (0.2, 0.6)):  # a range missing scores clips them
        got = jax.jit(lambda s, l, r: binned_anomaly_metrics(s, l, num_bins=16, score_range=r))(
            scores, labels, score_range)
        assert_within_bound(got, scores, labels)


def test_bins_on_distinct_scores_give_the_exact_metrics():
    scores, labels = random_maps(2, 1, levels=8)
    scores = np.clip(scores, -2, 2)[0]  # values k / 8 in [-2, 2]: one bin each of 33 on [-2, 2 + 1/8)
    got = binned_anomaly_metrics(scores, labels[0], num_bins=33, score_range=(-2.0, 2.125))
    exact = anomaly_metrics(scores, labels[0])
    for metric, _ in METRICS:
        np.testing.assert_allclose(float(got[metric]), exact[metric], rtol=1e-6)
    assert float(got["threshold_at_tpr"]) == exact["threshold_at_tpr"]
    # every bin holds one distinct score: the bounds are the float32 rounding term alone
    assert all(float(got[bound]) < 1e-4 for _, bound in METRICS)


def test_undefined_metrics_are_nan_without_a_host_read():
    scores, labels = random_maps(3, 3)
    labels[0] = 255  # all void
    labels[1][labels[1] == 1] = 0  # no positive
    scores[2][labels[2] == 0] = np.nan  # a NaN score on a non-void pixel
    got = jax.jit(jax.vmap(binned_anomaly_metrics))(scores, labels)
    for key in ("ap", "auroc", "fpr_at_tpr", "threshold_at_tpr", "ap_error_bound"):
        assert np.isnan(np.asarray(got[key])).all(), key
    assert int(got["num_positives"][0]) == 0 and int(got["num_negatives"][0]) == 0


def test_huge_and_infinite_scores():
    scores, labels = random_maps(4, 1)
    scores, labels = scores[0], labels[0]
    huge = scores / np.abs(scores).max() * np.float32(3e38)  # a span above float32's largest: halved first
    got = jax.jit(binned_anomaly_metrics)(huge, labels)
    assert_within_bound(got, huge, labels)
    assert float(got["auroc_error_bound"]) < 1e-3
    infinite = scores.copy()
    infinite.flat[np.flatnonzero(labels == 1)[:3]] = np.inf
    infinite[0, :4] = -np.inf
    assert_within_bound(jax.jit(binned_anomaly_metrics)(infinite, labels), infinite, labels)


def test_sorted_metrics_are_the_exact_ones_under_jit_and_vmap():
    scores, labels = random_maps(9, 3)
    scores[1] = np.round(scores[1] * 4) / 4  # ties
    labels[2] = 255  # all void: NaN
    settings = dict(tpr=0.9, fpr_convention="interp", ap_convention="envelope")
    metric = jax.jit(jax.vmap(lambda s, l: sorted_anomaly_metrics(s, l, **settings)))
    got = metric(scores, labels)
    with jax.enable_x64(True):  # float64 sums: anomaly_metrics' numbers
        got64 = metric(scores, labels)
    for i in range(2):
        exact = assert_within_bound({k: v[i] for k, v in got.items()}, scores[i], labels[i], **settings)
        for name, _ in METRICS:
            np.testing.assert_allclose(float(got64[name][i]), exact[name], rtol=1e-12, err_msg=name)
        assert float(got["threshold_at_tpr"][i]) == exact["threshold_at_tpr"]
        assert float(got["auroc_error_bound"][i]) < 2e-4  # the float32 rounding alone: 2 (K' + 16) u
    assert np.isnan(np.asarray(got["ap"][2])) and np.isnan(np.asarray(got64["fpr_at_tpr"][2]))


def test_histogram_of_a_huge_range_equals_numpy():
    rng = np.random.default_rng(5)
    scores = (rng.uniform(-1, 1, 500) * 3e38).astype(np.float32)
    labels = rng.integers(0, 2, 500).astype(np.uint8)
    got = np.asarray(score_histogram(scores, labels, -3e38, 3e38, 64))
    edges = np.linspace(-3e38, 3e38, 65)
    for label in (0, 1):
        expected, _ = np.histogram(scores[labels == label].astype(np.float64), edges)
        np.testing.assert_array_equal(got[:, label], expected)


def test_tpr_and_range_may_be_traced_and_64_bit_mode_is_float64():
    scores, labels = random_maps(6, 1, levels=16)
    tprs = jnp.asarray([0.5, 0.8, 0.95, 1.0])
    got = jax.jit(jax.vmap(lambda t: binned_anomaly_metrics(scores[0], labels[0], num_bins=256, tpr=t)))(tprs)
    for i, tpr in enumerate(np.asarray(tprs)):
        assert_within_bound({k: v[i] for k, v in got.items()}, scores[0], labels[0], tpr=float(tpr))
    with jax.enable_x64(True):
        got = jax.jit(binned_anomaly_metrics)(scores[0], labels[0])
        assert got["ap"].dtype == jnp.float64
    assert_within_bound(got, scores[0], labels[0])


def test_real_maps_within_the_bound():
    frames = real_frames("anomaly")
    if frames is None:
        pytest.skip("real SMIYC frames not found (set JAXANOM_REALDATA)")
    maps, labels = frames
    labels = np.stack(labels)[:, ::2, ::2]  # every other row and column: a quarter of the pixels
    for name in ("redness", "blurred_truth"):  # 256 levels (ties everywhere); a near-perfect score
        scores = np.stack(maps[name]).astype(np.float32)[:, ::2, ::2]
        got = jax.jit(binned_anomaly_metrics)(scores, labels)
        assert_within_bound(got, scores, labels)
        assert float(got["auroc_error_bound"]) < 1e-3 and float(got["fpr_error_bound"]) < 0.01


def test_static_options_are_checked_in_one_line():
    scores, labels = random_maps(7, 1)
    for settings, argument in ((dict(fpr_convention="nearest"), "fpr_convention"), (dict(ap_convention="x"), "ap_convention"),
                               (dict(num_bins=0), "num_bins"), (dict(tpr=1.5), "tpr")):
        with pytest.raises(InputError) as error:
            binned_anomaly_metrics(scores, labels, **settings)
        assert error.value.argument == argument and "\n" not in str(error.value)
    with pytest.raises(InputError, match="labels"):
        binned_anomaly_metrics(scores, labels.astype(np.float32))


def test_eight_smoothing_sigmas_scored_in_one_compiled_call():
    """SML with eight smoothing sigmas and its AP / AUROC / FPR95, all inside one jit(vmap(...)),
    equal the exact host metrics of the same maps within the returned bounds."""
    from jaxanom import sml

    rng = np.random.default_rng(8)
    logits = rng.normal(size=(2, 40, 56, 4)).astype(np.float32)
    labels = np.zeros((2, 40, 56), np.uint8)
    labels[:, 12:22, 20:34] = 1  # an anomaly: low logits there
    logits[labels == 1] -= 1.5
    labels[:, :3] = 255
    mean, std = np.zeros(4, np.float32), np.ones(4, np.float32)

    def one_sigma(sigma):
        maps = sml.sml_score_batch(logits, mean, std, sigma=sigma)
        return maps, binned_anomaly_metrics(maps, labels, num_bins=2048)

    sigmas = jnp.linspace(0.5, 4.0, 8)
    maps, got = jax.jit(jax.vmap(one_sigma))(sigmas)
    aps = []
    for i in range(len(sigmas)):
        aps.append(assert_within_bound({k: v[i] for k, v in got.items()}, np.asarray(maps[i]), labels)["ap"])
    assert float(got["ap_error_bound"].max()) < 0.02 and len(set(aps)) == len(aps)  # the sigmas differ


def test_smoothed_real_maps_scored_in_one_compiled_call():
    frames = real_frames("anomaly")
    if frames is None:
        pytest.skip("real SMIYC frames not found (set JAXANOM_REALDATA)")
    from jaxanom import sml

    maps, labels = frames
    scores, labels = np.asarray(maps["redness"][0])[::4, ::4], labels[0][::4, ::4]
    smoothed, got = jax.jit(jax.vmap(lambda s: (lambda m: (m, binned_anomaly_metrics(m, labels)))(
        sml.dilated_smoothing(scores, sigma=s))))(jnp.asarray([0.5, 2.0]))
    for i in range(2):
        assert_within_bound({k: v[i] for k, v in got.items()}, np.asarray(smoothed[i]), labels)
