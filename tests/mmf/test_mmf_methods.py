"""MMF rows of jaxanom.method_registry (mmf, mmf_raw, resynthesis, resynthesis_post) and the pipeline's batches."""
from types import SimpleNamespace

import jax
import numpy as np
import pytest
from test_mmf_postprocess import dense_eq6

from jaxanom import method_registry
from jaxanom.app.mmf_pipeline import training_stream
from jaxanom.mmf.postprocess import superpixel_score_batch


def _maps(rng, b=2, h=8, w=12):
    return {"mmf": rng.random((b, h, w)).astype(np.float32), "resynthesis": rng.random((b, h, w)).astype(np.float32),
            "superpixels": rng.integers(0, 6, (b, h, w)).astype(np.int32), "num_segments": 6}


def test_raw_rows_are_the_dissimilarity_maps_and_post_rows_apply_eq6_with_the_road_probability():
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(2, 8, 12, 4)).astype(np.float32) * 3
    maps = _maps(rng)
    np.testing.assert_array_equal(method_registry.score("mmf_raw", {"logits": logits, "mmf_maps": maps}), maps["mmf"])
    np.testing.assert_array_equal(method_registry.score("resynthesis", {"logits": logits, "mmf_maps": maps}),
                                  maps["resynthesis"])
    e = np.exp(logits.astype(np.float64) - logits.max(-1, keepdims=True))
    road = e[..., 0] / e.sum(-1)  # road = class 0
    for name, source in (("mmf", "mmf"), ("resynthesis_post", "resynthesis")):
        # an independent composition: softmax and Eq. 6 in NumPy (test_mmf_postprocess.dense_eq6)
        expected = [dense_eq6(maps[source][b], road[b], maps["superpixels"][b], 6)[maps["superpixels"][b]]
                    for b in range(2)]
        got = method_registry.score(name, {"logits": logits, "mmf_maps": maps})
        np.testing.assert_allclose(got, expected, atol=1e-5)


def test_post_rows_read_their_own_segmentation():
    # slic_input="anomaly": the resynthesis rows use "superpixels_resynthesis", the mmf rows "superpixels"
    rng = np.random.default_rng(1)
    logits = rng.normal(size=(2, 8, 12, 4)).astype(np.float32)
    maps = dict(_maps(rng), superpixels_resynthesis=rng.integers(0, 6, (2, 8, 12)).astype(np.int32))
    road = np.asarray(jax.nn.softmax(logits, -1)[..., 0])
    for name, source, labels in (("mmf", "mmf", "superpixels"), ("resynthesis_post", "resynthesis",
                                                                  "superpixels_resynthesis")):
        expected = superpixel_score_batch(maps[source], road, maps[labels], 6)
        got = method_registry.score(name, {"logits": logits, "mmf_maps": maps})
        np.testing.assert_allclose(got, expected, atol=1e-6)


def test_dissimilarity_inputs_are_the_anomaly_map_and_the_distance():
    # u = [A, D] (A = U ⊙ L), not [U, D]: docs/papers/mmf.md#dissimilarity-network
    from jaxanom.app.mmf_pipeline import MMFPipeline

    rng = np.random.default_rng(2)
    frames = [{"image": rng.integers(0, 256, (8, 16, 3), dtype=np.uint8), "void": rng.random((8, 16)) < 0.1}
              for _ in range(2)]
    out = {k: rng.random((2, 8, 16)).astype(np.float32) for k in ("anomaly", "distance", "entropy", "perceptual")}
    out.update(resynthesis_normalized=rng.random((2, 8, 16, 3)).astype(np.float32),
               prediction=rng.integers(0, 3, (2, 8, 16)), prediction_depth=rng.integers(0, 3, (2, 8, 16)))
    pipeline = SimpleNamespace(config=SimpleNamespace(dissim_variants=()))  # no control net: no synthesizer call
    inputs = MMFPipeline._dissimilarity_inputs(pipeline, frames, out)
    np.testing.assert_array_equal(inputs["uncertainty"][..., 0], out["anomaly"])
    np.testing.assert_array_equal(inputs["uncertainty"][..., 1], out["distance"])
    np.testing.assert_array_equal(inputs["label"], np.stack([f["void"] for f in frames]).astype(np.int32))
    np.testing.assert_array_equal(inputs["semantic"], out["prediction"])
    np.testing.assert_array_equal(inputs["semantic_depth"], out["prediction_depth"])


@pytest.mark.parametrize("slic_input,connectivity", [("image", False), ("anomaly", True)])
def test_segment_follows_the_config(slic_input, connectivity):
    from jaxanom.mmf.training_free import segment
    from jaxanom.superpixels import rgb_to_lab, slic

    rng = np.random.default_rng(3)
    images = rng.integers(0, 256, (2, 16, 32, 3), dtype=np.uint8)
    anomaly = {"superpixels": rng.random((2, 16, 32)).astype(np.float32),
               "superpixels_resynthesis": rng.random((2, 16, 32)).astype(np.float32)}
    out = segment(images, anomaly, step=4 if connectivity else None, slic_input=slic_input, connectivity=connectivity)
    if slic_input == "image":  # scaled step: S = round(8 sqrt(16 * 32 / (256 * 512))) = 1, one pixel each
        assert set(out) == {"superpixels", "num_segments"} and out["num_segments"] == 512
        np.testing.assert_array_equal(out["superpixels"][1], slic(rgb_to_lab(images[1]), 1))
    else:
        assert out["num_segments"] == 32
        for name, value in anomaly.items():
            np.testing.assert_array_equal(out[name][1], slic(100 * value[1, ..., None], 4, connectivity=True))


def test_segment_scales_the_step_with_the_frame_not_the_batch():
    from jaxanom.mmf.training_free import segment
    from jaxanom.superpixels import rgb_to_lab, slic

    images = np.random.default_rng(5).integers(0, 256, (1, 64, 128, 3), dtype=np.uint8)
    out = segment(images, {})  # S = round(8 sqrt(64 * 128 / (256 * 512))) = 2
    np.testing.assert_array_equal(out["superpixels"][0], slic(rgb_to_lab(images[0]), 2))


@pytest.mark.parametrize("field,value,message", [("slic_step", 0, "slic_step"), ("slic_step", 2.5, "slic_step"),
                                                 ("slic_input", "rgb", "slic_input")])
def test_config_rejects_bad_slic_settings(field, value, message):
    from jaxanom.app.mmf_pipeline import MMFConfig

    with pytest.raises(ValueError, match=message):
        MMFConfig(**{field: value})


def test_mmf_rows_need_the_maps():
    with pytest.raises(ValueError, match="MMF's maps"):
        method_registry.check(["entropy", "mmf"], {"logits"})
    assert method_registry.check(["mmf"], {"logits", "mmf_maps"}) == ("mmf",)


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


def test_dissimilarity_training_is_class_weighted(tmp_path):
    from jaxanom.app.mmf_pipeline import MMFConfig, _dissimilarity_train_config

    labels = np.zeros((2, 10, 10), np.int32)
    labels[0, :2, :2] = 1  # 4 of 200 pixels
    labels[1, -1] = 255
    weighted = _dissimilarity_train_config(MMFConfig(), tmp_path, "mmf", False, labels)
    np.testing.assert_allclose(weighted.objective.class_weights, [190 / (2 * 186), 190 / (2 * 4)])
    assert _dissimilarity_train_config(MMFConfig(dissim_balance=False), tmp_path, "mmf", False,
                                       labels).objective.class_weights is None
    assert MMFConfig().part_key("dissimilarity") != MMFConfig(dissim_balance=False).part_key("dissimilarity")


def test_training_free_maps_on_a_real_frame_with_any_network(road_anomaly_sample):
    # no trained MMF part and no synthetic data: any network's logits (here random) on a real frame
    import cv2

    from jaxanom.mmf.training_free import training_free_maps
    from jaxanom.superpixels import rgb_to_lab, slic

    path = sorted((road_anomaly_sample / "frames").glob("*.jpg"))[0]
    image = cv2.resize(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB), (64, 32), interpolation=cv2.INTER_AREA)
    logits = np.random.default_rng(4).normal(size=(1, 32, 64, 5)).astype(np.float32) * 2
    out = training_free_maps(logits, image[None], step=4)
    p = np.exp(logits[0].astype(np.float64))
    p /= p.sum(-1, keepdims=True)
    entropy = -np.sum(p * np.log2(p), -1) / np.log2(5)  # Eq. 1, normalised by log2 C
    np.testing.assert_allclose(out["entropy"][0], entropy, atol=1e-5)
    np.testing.assert_allclose(out["road"][0], p[..., 0], atol=1e-6)
    labels = np.asarray(slic(rgb_to_lab(image), 4))
    np.testing.assert_array_equal(out["superpixels"][0], labels)
    np.testing.assert_allclose(out["entropy_post"][0], dense_eq6(entropy, p[..., 0], labels, 128)[labels], atol=1e-4)
    with pytest.raises(ValueError, match="images: expected"):
        training_free_maps(logits, image[None, :16])
