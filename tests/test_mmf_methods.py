"""MMF rows of jaxanom.methods (mmf, mmf_raw, resynthesis, resynthesis_post) and the pipeline's batches."""
import numpy as np
import pytest

from jaxanom import methods
from jaxanom.mmf.pipeline import training_stream
from jaxanom.mmf.postprocess import superpixel_score_batch


def _maps(rng, b=2, h=8, w=12):
    return {"mmf": rng.random((b, h, w)).astype(np.float32), "resynthesis": rng.random((b, h, w)).astype(np.float32),
            "superpixels": rng.integers(0, 6, (b, h, w)).astype(np.int32), "num_segments": 6}


def test_raw_rows_are_the_dissimilarity_maps_and_post_rows_apply_eq6_with_the_road_probability():
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(2, 8, 12, 4)).astype(np.float32) * 3
    maps = _maps(rng)
    np.testing.assert_array_equal(methods.score_batch("mmf_raw", logits, mmf_maps=maps), maps["mmf"])
    np.testing.assert_array_equal(methods.score_batch("resynthesis", logits, mmf_maps=maps), maps["resynthesis"])
    e = np.exp(logits.astype(np.float64) - logits.max(-1, keepdims=True))
    road = (e[..., 0] / e.sum(-1)).astype(np.float32)
    for name, source in (("mmf", "mmf"), ("resynthesis_post", "resynthesis")):
        expected = superpixel_score_batch(maps[source], road, maps["superpixels"], 6)
        np.testing.assert_allclose(methods.score_batch(name, logits, mmf_maps=maps), expected, atol=1e-6)


def test_mmf_rows_need_the_maps():
    with pytest.raises(ValueError, match="MMF's maps"):
        methods.check_methods(["entropy", "mmf"], have_stats=False, have_attention=False)
    assert methods.check_methods(["mmf"], have_stats=False, have_attention=False, have_mmf=True) == ("mmf",)


def test_training_stream_is_deterministic_and_flips_every_entry_together():
    rng = np.random.default_rng(0)
    arrays = {"image": rng.integers(0, 256, (5, 4, 6, 3), dtype=np.uint8),
              "label": rng.integers(0, 2, (5, 4, 6)).astype(np.int32)}
    arrays["copy"] = arrays["label"].copy()
    a, b = training_stream(arrays, 3, seed=1), training_stream(arrays, 3, seed=1)
    for _ in range(4):
        x, y = next(a), next(b)
        for key in arrays:
            np.testing.assert_array_equal(x[key], y[key])
        np.testing.assert_array_equal(x["label"], x["copy"])
        for i in range(3):  # each example is a frame of the source, maybe mirrored
            assert any(np.array_equal(x["image"][i], f) or np.array_equal(x["image"][i], f[:, ::-1])
                       for f in arrays["image"])
