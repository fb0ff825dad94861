"""``mmf_pipeline``'s extra dissimilarity nets (ablations and a control): each ablation net reads
what its name says and nothing else, the control net reads the resynthesis of the ground truth,
and the variants leave the keys of the existing parts alone."""
import dataclasses

import numpy as np
import pytest

from jaxanom.app import mmf_pipeline as pipeline
from jaxanom.data.transforms import normalize
from jaxanom.mmf.synthesis import ClassMeanSynthesizer

QUICK = pipeline.MMFConfig.quick()


@pytest.mark.parametrize("name, reads, ignores", [
    ("mmf", {"semantic_depth", "uncertainty"}, set()),
    ("resynthesis", set(), {"semantic_depth", "uncertainty"}),
    ("no_depth", {"uncertainty"}, {"semantic_depth"}),
    ("no_uncertainty", {"semantic_depth"}, {"uncertainty"}),
    ("truth_resynthesis", set(), {"semantic_depth", "uncertainty"}),
])
def test_each_net_reads_its_inputs(name, reads, ignores):
    model = pipeline._dissimilarity_model(QUICK, name)
    assert {"resynthesis", "semantic"} | reads <= set(model.extra_inputs)
    assert not ignores & set(model.extra_inputs)
    assert model.uncertainty_channels == (2 if "uncertainty" in reads else 0)


def test_variants_are_validated_and_leave_the_other_parts_keys_alone():
    with_variants = dataclasses.replace(QUICK, dissim_variants=tuple(pipeline.DISSIM_VARIANTS))
    for part in ("segmenter", "rgbd", "synthesizer", "dissimilarity"):
        assert with_variants.part_key(part) == QUICK.part_key(part)
    assert pipeline.dissimilarity_names(with_variants) == ("mmf", "resynthesis", *pipeline.DISSIM_VARIANTS)
    dirs = {pipeline._run_dir(with_variants, pipeline.Path("r"), "dissimilarity", n)
            for n in pipeline.dissimilarity_names(with_variants)}
    assert len(dirs) == 5  # one folder per net
    for bad in (("depthless",), ["no_depth"], "no_depth"):
        with pytest.raises(ValueError, match="dissim_variants"):
            dataclasses.replace(QUICK, dissim_variants=bad)


def test_control_net_reads_the_ground_truth_resynthesis():
    rng = np.random.default_rng(0)
    classes = QUICK.segmenter.num_classes
    means = rng.random((classes + 1, 3)).astype(np.float32)
    config = dataclasses.replace(QUICK, dissim_variants=("truth_resynthesis",))
    pipe = pipeline.MMFPipeline(config, None, None, ClassMeanSynthesizer(means), {})
    semantic = rng.integers(0, classes, (2, 8, 16)).astype(np.uint8)
    semantic[0, 2:5, 3:9] = 255  # an anomaly or void clutter: painted as unknown (the global mean, row C)
    frames = [{"image": rng.integers(0, 256, (8, 16, 3), dtype=np.uint8), "semantic": s} for s in semantic]
    out = {"resynthesis_normalized": rng.random((2, 8, 16, 3)).astype(np.float32),
           "prediction": rng.integers(0, classes, (2, 8, 16)).astype(np.int32),
           "prediction_depth": rng.integers(0, classes, (2, 8, 16)).astype(np.int32),
           "anomaly": rng.random((2, 8, 16)).astype(np.float32), "distance": rng.random((2, 8, 16)).astype(np.float32)}
    inputs = pipe._dissimilarity_inputs(frames, out)
    painted = means[np.where(semantic == 255, classes, semantic)]  # NumPy: row c for class c, row C for 255
    expected = np.asarray(normalize(np.round(painted * 255).astype(np.uint8)))
    np.testing.assert_allclose(inputs["resynthesis_truth"], expected, atol=1e-6)
    control = pipeline._net_inputs(inputs, "truth_resynthesis", pipeline._dissimilarity_model(config, "truth_resynthesis"))
    plain = pipeline._net_inputs(inputs, "resynthesis", pipeline._dissimilarity_model(config, "resynthesis"))
    assert control["resynthesis"] is inputs["resynthesis_truth"] and plain["resynthesis"] is out["resynthesis_normalized"]
    np.testing.assert_array_equal(control["semantic"], out["prediction"])  # only the resynthesis differs
    # without the control net nothing of the ground truth is computed
    plain_pipe = pipeline.MMFPipeline(QUICK, None, None, ClassMeanSynthesizer(means), {})
    assert "resynthesis_truth" not in plain_pipe._dissimilarity_inputs(frames, out)


def test_scored_batch_gives_the_mmf_rows_the_named_net():
    rng = np.random.default_rng(1)
    maps = {k: rng.random((2, 4, 8)).astype(np.float32) for k in ("mmf", "resynthesis_score", "dissim_no_depth")}
    maps.update(logits=np.zeros((2, 4, 8, 3), np.float32), num_segments=2, superpixels=np.zeros((2, 4, 8), np.int32),
                superpixels_no_depth=np.ones((2, 4, 8), np.int32))
    frames = [{"label": np.zeros((4, 8), np.uint8)}] * 2
    assert pipeline.scored_batch(frames, maps)["mmf_maps"]["mmf"] is maps["mmf"]
    batch = pipeline.scored_batch(frames, maps, "no_depth")["mmf_maps"]
    assert batch["mmf"] is maps["dissim_no_depth"] and batch["resynthesis"] is maps["resynthesis_score"]
    assert batch["superpixels"] is maps["superpixels_no_depth"]  # its own segmentation where it has one
    with pytest.raises(ValueError, match="net"):
        pipeline.scored_batch(frames, maps, "no_uncertainty")


def test_a_config_with_variants_round_trips_through_json():
    import json

    from jaxanom.app.mmf_experiment import MMFDemoConfig
    from jaxanom.config_codec import decode, encode

    config = MMFDemoConfig(pipeline=dataclasses.replace(QUICK, dissim_variants=("no_depth", "truth_resynthesis")))
    assert decode(MMFDemoConfig, json.loads(json.dumps(encode(config)))) == config
