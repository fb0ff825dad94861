"""MMF Eq. 6 (superpixel anomaly scores) against a hand-worked example and a NumPy loop."""
import jax
import numpy as np
import pytest

from jaxanom.mmf.postprocess import superpixel_score, superpixel_score_batch, superpixel_scores


def reference_scores(anomaly, road, labels, k, include_self=False):
    """Eq. 6 as docs/papers/mmf.md#superpixel-scores reads it, one superpixel at a time, float64."""
    height, width = labels.shape
    ids = [j for j in range(k) if np.any(labels == j)]
    stats = {}
    for j in ids:
        ys, xs = np.nonzero(labels == j)
        stats[j] = dict(n=len(ys) / (height * width), alpha=anomaly[ys, xs].astype(np.float64).mean(),
                        p=road[ys, xs].astype(np.float64).mean(), c=np.array([ys.mean(), xs.mean()]))
    pairs = [np.linalg.norm(stats[i]["c"] - stats[j]["c"]) for a, i in enumerate(ids) for j in ids[a + 1:]]
    omega = np.median(pairs) if pairs else np.nan
    raw = np.zeros(k)
    for i in ids:
        total = 0.0
        for j in ids:
            if j == i and not include_self:
                continue
            r = np.linalg.norm(stats[i]["c"] - stats[j]["c"])
            total += stats[j]["p"] * stats[j]["n"] * (1.0 if r == 0 else np.exp(-r**2 / (2 * omega**2)))
        raw[i] = stats[i]["alpha"] * total
    values = raw[ids]
    out = np.zeros(k)
    if values.max() > values.min():
        out[ids] = (values - values.min()) / (values.max() - values.min())
    return out


def test_hand_worked_two_by_three():
    # superpixel 0 = top-left pair, 1 = right column, 2 = bottom-left pair; each has 2 of 6
    # pixels, so n = 1/3. alpha = (0.3, 0.9, 0.3); p = (1, 0, 0.5); centroids (0, 0.5),
    # (0.5, 2), (1, 0.5) -> r01 = r12 = sqrt(2.5), r02 = 1; omega = median = sqrt(2.5), so
    # 2 omega^2 = 5 and the weights are w01 = w12 = e^-0.5, w02 = e^-0.2.
    labels = np.array([[0, 0, 1], [2, 2, 1]])
    anomaly = np.array([[0.2, 0.4, 1.0], [0.0, 0.6, 0.8]], np.float32)
    road = np.array([[1.0, 1.0, 0.0], [0.5, 0.5, 0.0]], np.float32)
    s0 = 0.3 * (0.0 * (1 / 3) * np.exp(-0.5) + 0.5 * (1 / 3) * np.exp(-0.2))  # = 0.05 e^-0.2
    s1 = 0.9 * (1.0 * (1 / 3) * np.exp(-0.5) + 0.5 * (1 / 3) * np.exp(-0.5))  # = 0.45 e^-0.5
    s2 = 0.3 * (1.0 * (1 / 3) * np.exp(-0.2) + 0.0 * (1 / 3) * np.exp(-0.5))  # = 0.1 e^-0.2
    assert s0 < s2 < s1  # so min-max gives 0, (s2 - s0) / (s1 - s0), 1
    expected = np.array([0.0, 1.0, (s2 - s0) / (s1 - s0)])
    scores, valid = superpixel_scores(anomaly, road, labels, 3)
    np.testing.assert_allclose(np.asarray(scores), expected, rtol=1e-5, atol=1e-7)
    assert np.asarray(valid).all()
    score_map = np.asarray(superpixel_score(anomaly, road, labels, 3))
    np.testing.assert_allclose(score_map, expected[labels], rtol=1e-5, atol=1e-7)
    assert score_map.dtype == np.float32


def random_case(rng, height, width, k, used):
    ids = rng.choice(k, size=used, replace=False)  # some ids stay empty
    labels = ids[rng.integers(0, used, (height, width))]
    labels.ravel()[:used] = ids  # every chosen id has a pixel
    return rng.random((height, width)).astype(np.float32), rng.random((height, width)).astype(np.float32), labels


@pytest.mark.parametrize("height,width,k,used,include_self", [
    (7, 9, 12, 8, False), (15, 11, 30, 30, False), (15, 11, 30, 17, True), (4, 5, 6, 2, False),
])
def test_matches_numpy_loop(height, width, k, used, include_self):
    anomaly, road, labels = random_case(np.random.default_rng(height * k), height, width, k, used)
    scores, valid = superpixel_scores(anomaly, road, labels, k, include_self=include_self)
    expected = reference_scores(anomaly, road, labels, k, include_self)
    np.testing.assert_allclose(np.asarray(scores), expected, rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(valid), np.isin(np.arange(k), labels))


def test_blocky_labels_like_slic_match_numpy():
    # contiguous blocks: centroid distances repeat exactly, so omega sits on ties
    rng = np.random.default_rng(7)
    labels = (np.arange(12)[:, None] // 4) * 5 + np.arange(20)[None, :] // 4
    anomaly, road = rng.random((2, 12, 20)).astype(np.float32)
    np.testing.assert_allclose(np.asarray(superpixel_scores(anomaly, road, labels, 15)[0]),
                               reference_scores(anomaly, road, labels, 15), rtol=1e-4, atol=1e-5)


def test_invariant_to_relabelling():
    rng = np.random.default_rng(1)
    anomaly, road, labels = random_case(rng, 13, 17, 20, 14)
    permutation = rng.permutation(20)
    before = np.asarray(superpixel_score(anomaly, road, labels, 20))
    after = np.asarray(superpixel_score(anomaly, road, permutation[labels], 20))
    np.testing.assert_allclose(after, before, rtol=1e-5, atol=1e-6)


def test_no_road_and_single_superpixel_give_zero():
    rng = np.random.default_rng(2)
    anomaly, road, labels = random_case(rng, 9, 10, 8, 8)
    np.testing.assert_array_equal(np.asarray(superpixel_score(anomaly, np.zeros_like(road), labels, 8)), 0.0)
    np.testing.assert_array_equal(np.asarray(superpixel_score(anomaly, road, np.full((9, 10), 3), 8)), 0.0)


def test_monotone_in_anomaly_of_one_superpixel():
    rng = np.random.default_rng(3)
    anomaly, road, labels = random_case(rng, 12, 12, 10, 10)
    before = np.asarray(superpixel_scores(anomaly, road, labels, 10)[0])
    raised = np.where(labels == 4, np.minimum(anomaly + 0.5, 1.0), anomaly)
    after = np.asarray(superpixel_scores(raised, road, labels, 10)[0])
    assert after[4] >= before[4]


def test_batch_matches_single_and_callers_jit():
    rng = np.random.default_rng(4)
    cases = [random_case(rng, 10, 14, 16, 11) for _ in range(3)]
    anomaly, road, labels = (np.stack(x) for x in zip(*cases))
    batch = np.asarray(superpixel_score_batch(anomaly, road, labels, 16))
    for b in range(3):
        np.testing.assert_allclose(batch[b], np.asarray(superpixel_score(anomaly[b], road[b], labels[b], 16)), atol=1e-6)
    vmapped = jax.vmap(lambda a, r, l: superpixel_score(a, r, l, 16))(anomaly, road, labels)  # the caller's vmap
    np.testing.assert_allclose(np.asarray(vmapped), batch, atol=1e-6)
    wrapped = jax.jit(lambda a: superpixel_score(a, road[0], labels[0], 16))
    np.testing.assert_allclose(np.asarray(wrapped(anomaly[0])), batch[0], atol=1e-6)


@pytest.mark.parametrize("args,message", [
    ((np.zeros((4, 5, 1)), np.zeros((4, 5)), np.zeros((4, 5), int), 3), "anomaly must have rank 2"),
    ((np.zeros((4, 5)), np.zeros((4, 6)), np.zeros((4, 5), int), 3), "road_probability must have the shape"),
    ((np.zeros((4, 5)), np.zeros((4, 5)), np.zeros((5, 4), int), 3), "labels must have the shape"),
    ((np.zeros((4, 5)), np.zeros((4, 5)), np.zeros((4, 5)), 3), "labels must hold integer"),
    ((np.zeros((4, 5)), np.zeros((4, 5)), np.full((4, 5), 3), 3), r"labels must lie in \[0, num_segments\)"),
    ((np.zeros((4, 5)), np.zeros((4, 5)), np.full((4, 5), -1), 3), r"labels must lie in"),
    ((np.zeros((4, 5)), np.zeros((4, 5)), np.zeros((4, 5), int), 0), "num_segments must be"),
    ((np.full((4, 5), np.nan), np.zeros((4, 5)), np.zeros((4, 5), int), 3), "anomaly must be finite"),
    ((np.zeros((4, 5)), np.full((4, 5), np.nan), np.zeros((4, 5), int), 3), "road_probability must be finite"),
])
def test_bad_input_raises(args, message):
    with pytest.raises(ValueError, match=message):
        superpixel_score(*args)


@pytest.mark.parametrize("block_rows", [0, 2.0, -3])
def test_bad_block_rows_raise(block_rows):
    with pytest.raises(ValueError, match="block_rows must be None or an integer >= 1"):
        superpixel_scores(np.zeros((4, 5)), np.zeros((4, 5)), np.zeros((4, 5), int), 3, block_rows=block_rows)


def test_batch_needs_rank_three():
    with pytest.raises(ValueError, match="anomaly must have rank 3"):
        superpixel_score_batch(np.zeros((4, 5)), np.zeros((4, 5)), np.zeros((4, 5), int), 3)


@pytest.mark.parametrize("k,used,spread,rows", [(9, 9, False, None), (10, 6, False, 3), (40, 33, False, 7),
                                                (5, 1, False, None), (9, 9, True, 1), (10, 10, True, None),
                                                (23, 20, True, 4)])
def test_median_distance_matches_numpy(k, used, spread, rows):
    from jaxanom.mmf.postprocess import _block_rows, _median_distance

    rng = np.random.default_rng(k + 100 * spread)
    if spread:  # continuous distances over decades: the two middle values sit in different radix buckets
        centres = (rng.random((k, 2)) * 10.0 ** rng.integers(-2, 4, (k, 1))).astype(np.float32)
    else:  # repeated distances: ties
        centres = rng.integers(0, 6, (k, 2)).astype(np.float32) / 2
    valid = np.zeros(k, bool)
    valid[rng.choice(k, used, replace=False)] = True
    i, j = np.triu_indices(k, 1)
    pairs = np.sqrt(np.sum((centres[i] - centres[j]) ** 2, axis=1, dtype=np.float32))[valid[i] & valid[j]]
    got = float(_median_distance(jax.numpy.asarray(centres), jax.numpy.asarray(valid), _block_rows(k, rows)))
    if pairs.size:  # odd and even pair counts (36, 15, 528, 45, 190)
        assert got == pytest.approx(np.median(pairs), rel=1e-6)
    else:
        assert np.isnan(got)


def dense_eq6(anomaly, road, labels, k, include_self=False):
    """Eq. 6 in NumPy float64 with the whole K x K matrix (vectorised; independent of the loop above)."""
    flat = labels.ravel()
    counts = np.bincount(flat, minlength=k).astype(np.float64)
    valid = counts > 0
    mean = lambda v: np.bincount(flat, v.ravel().astype(np.float64), minlength=k) / np.maximum(counts, 1)  # noqa: E731
    ys, xs = np.mgrid[:labels.shape[0], :labels.shape[1]]
    centres = np.stack([mean(ys), mean(xs)], 1)
    r = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    i, j = np.triu_indices(k, 1)
    both = valid[i] & valid[j]
    omega = np.median(r[i, j][both]) if both.any() else np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        weight = np.where(r == 0, 1.0, np.exp(-r**2 / (2 * omega**2)))
    pair = valid[None] & (np.ones((k, k), bool) if include_self else ~np.eye(k, dtype=bool))
    score = mean(anomaly) * np.sum(np.where(pair, mean(road) * counts / labels.size * weight, 0.0), axis=1)
    out = np.zeros(k)
    low, high = score[valid].min(), score[valid].max()
    if high > low:
        out[valid] = (score[valid] - low) / (high - low)
    return out


@pytest.mark.parametrize("height,width,k,used,include_self,block_rows", [
    (13, 17, 30, 23, False, 4), (13, 17, 30, 23, False, None), (9, 31, 41, 41, True, 7), (9, 31, 41, 41, False, 1),
    (5, 3, 11, 1, False, 3), (1, 1, 3, 1, True, 2), (11, 7, 50, 2, False, 64),
])
def test_blockwise_matches_dense_numpy(height, width, k, used, include_self, block_rows):
    # K not a multiple of the block, empty ids, a single superpixel, a 1x1 image, two superpixels
    anomaly, road, labels = random_case(np.random.default_rng(height * width + k), height, width, k, used)
    scores, valid = superpixel_scores(anomaly, road, labels, k, include_self=include_self, block_rows=block_rows)
    np.testing.assert_allclose(np.asarray(scores), dense_eq6(anomaly, road, labels, k, include_self),
                               rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(valid), np.isin(np.arange(k), labels))


def test_memory_grows_with_k_not_k_squared():
    # XLA's own account of the compiled program's scratch memory, at K = 8192 (dense pairs: 256 MB a float32 array)
    from jaxanom.mmf.postprocess import _superpixel_scores_jit

    shape, k = (64, 128), 8192
    args = (jax.numpy.zeros(shape), jax.numpy.zeros(shape), jax.numpy.zeros(shape, jax.numpy.int32))
    compiled = _superpixel_scores_jit.lower(*args, num_segments=k, block_rows=16).compile()
    assert compiled.memory_analysis().temp_size_in_bytes < 16 * 2**20


@pytest.mark.parametrize("centres,rows", [
    ([[1.0, 2.0]] * 5 + [[4.0, 6.0]], 2),  # 10 of 15 pairs coincide: omega = 0
    ([[1.0, 2.0]] * 3 + [[4.0, 6.0]], None),  # 3 of 6 pairs at 0, 3 at 5: omega = (0 + 5) / 2
    ([[0.0, 0.0]] * 4, 3),  # every centroid equal: omega = 0
])
def test_median_distance_with_coincident_centroids(centres, rows):
    from jaxanom.mmf.postprocess import _block_rows, _median_distance

    centres = np.array(centres, np.float32)
    i, j = np.triu_indices(len(centres), 1)
    expected = np.median(np.linalg.norm(centres[i] - centres[j], axis=1))
    got = _median_distance(jax.numpy.asarray(centres), jax.numpy.ones(len(centres), bool),
                           _block_rows(len(centres), rows))
    assert float(got) == expected
