"""``experiments/mmf_table2.py``: seeds, findings on the right rows, and the whole table path with
untrained parts (the training itself is covered by ``test_mmf_demo``)."""
import dataclasses
import functools
import json
import types

import numpy as np
import pytest

from experiments import mmf_table2 as exp
from experiments.__main__ import EXPERIMENTS, write_results
from experiments.common import Scale
from jaxanom.app.experiment import build_network
from jaxanom.app import mmf_pipeline as pipeline
from jaxanom.train.step import model_input
from tiny_models import random_variables


def test_seeds_sizes_and_smoke_detection():
    assert exp.is_smoke(Scale.smoke()) and exp.is_smoke(dataclasses.replace(Scale.smoke(), seed=5))
    assert not exp.is_smoke(Scale()) and not exp.is_smoke(dataclasses.replace(Scale.smoke(), steps=3))
    quick = exp.demo_config(dataclasses.replace(Scale.smoke(), seed=2))
    assert quick.pipeline.segmenter.train.seed == 6 and quick.anomaly_frames == Scale.smoke().anomaly_frames
    quick_config = pipeline.MMFConfig.quick()
    assert dataclasses.replace(quick.pipeline, segmenter=quick_config.segmenter, dissim_variants=(),
                               gan_steps=quick_config.gan_steps) == quick_config
    assert quick.pipeline.dissim_variants == exp.PRESET.dissim_variants == tuple(pipeline.DISSIM_VARIANTS)
    assert exp.spade_config(quick.pipeline).synthesizer == "spade" and not exp.spade_config(quick.pipeline).dissim_variants
    full = exp.demo_config(Scale(seed=1))
    assert full.pipeline.segmenter.train.seed == 3 and full.anomaly_frames == exp.ANOMALY_FRAMES
    assert full.pipeline.dissim_steps == exp.PRESET.dissim_steps and full.pipeline.segmenter.height == 64
    # every part of another seed is another folder
    assert all(full.pipeline.part_key(p) != exp.demo_config(Scale(seed=2)).pipeline.part_key(p)
               for p in ("segmenter", "rgbd", "synthesizer", "dissimilarity"))
    with pytest.raises(ValueError, match="synthetic"):
        exp.demo_config(Scale(cityscapes_root="/data/cityscapes"))
    assert EXPERIMENTS[-1] == exp.NAME


def _values(ap: dict, fpr95: dict, std: float = 0.0, f1: dict | None = None) -> dict:
    f1 = f1 or dict.fromkeys(ap, 5.0)
    return {label: {"ap": ap[label], "fpr95": fpr95[label], "f1": f1[label], "ap_std": std, "fpr95_std": std,
                    "f1_std": std} for label in ap}


def _favourable():
    """AP, FPR95 and mean F1 where every claim of the paper and the control hold."""
    labels = [row.label for row in exp.ROWS]
    ap, fpr, f1 = dict.fromkeys(labels, 10.0), dict.fromkeys(labels, 90.0), dict.fromkeys(labels, 5.0)
    # only the assistant maps raise AP; only the post-processor lowers FPR95; MMF best in both
    ap.update({exp.ASSISTED: 30.0, exp.FULL: 40.0, exp.ENTROPY: 20.0, exp.CONTROL: 50.0, exp.SPADE_FULL: 30.0})
    fpr.update({exp.POST: 50.0, exp.FULL: 40.0, exp.ENTROPY: 60.0})
    f1[exp.FULL] = 20.0
    return ap, fpr, f1


def test_findings_read_the_rows_they_name():
    ap, fpr, f1 = _favourable()
    got = {f["claim"]: f["holds"] for f in exp.findings(_values(ap, fpr, f1=f1))}
    assert all(got.values()), got
    # the same with a spread larger than every difference: no comparison in favour holds
    spread = {f["claim"]: f["holds"] for f in exp.findings(_values(ap, fpr, std=100.0, f1=f1))}
    assert [c for c, h in spread.items() if h] == ["the assistant maps do not clearly lower FPR95"]
    # swap the roles of the two mechanisms: the mechanism-specific claims fail
    ap.update({exp.ASSISTED: 10.0, exp.POST: 30.0})
    fpr.update({exp.POST: 90.0, exp.ASSISTED: 50.0})
    swapped = {f["claim"]: f["holds"] for f in exp.findings(_values(ap, fpr, f1=f1))}
    assert not swapped["the assistant maps raise the resynthesis net's AP"]
    assert not swapped["the assistant maps do not clearly lower FPR95"]
    assert not swapped["the post-processor lowers the resynthesis net's FPR95"]


def test_depth_uncertainty_f1_synthesizer_and_control_findings_read_their_rows():
    ap, fpr, f1 = _favourable()
    claims = {f["claim"]: f for f in exp.findings(_values(ap, fpr, f1=f1))}
    depth, unc = "the depth semantics Ŝ_D add to MMF's AP (§IV-B: they complement)", "the uncertainty maps [A, D] add to MMF's AP"
    f1_claim, control = "Table 1: MMF has the best mean F1 of all rows", [c for c, f in claims.items() if f["control"]]
    assert len(control) == 1 and control[0].startswith("control:") and claims[control[0]]["status"] == "holds"
    for label, claim in ((exp.NO_DEPTH, depth), (exp.NO_UNCERTAINTY, unc), (exp.CONTROL, control[0])):
        worse = dict(ap, **{label: ap[exp.FULL if label != exp.CONTROL else exp.BASE] + 1})
        if label == exp.CONTROL:
            worse[label] = ap[exp.BASE] - 1
        got = {f["claim"]: f for f in exp.findings(_values(worse, fpr, f1=f1))}
        assert got[claim]["status"] == "fails" and not got[claim]["holds"]
        assert sum(not f["holds"] for f in got.values()) == 1, [c for c, f in got.items() if not f["holds"]]
    # mean F1 is read from the f1 metric: MMF's best AP does not make it hold
    got = {f["claim"]: f["holds"] for f in exp.findings(_values(ap, fpr, f1=dict(f1, **{"SML": 30.0})))}
    assert not got[f1_claim] and sum(not h for h in got.values()) == 1
    # Table 4: the better synthesizer is the one named by the resynthesis error
    table4 = "Table 4: the better synthesizer (lower resynthesis error) gives the higher AP"
    assert claims[table4]["holds"]
    assert not {f["claim"]: f["holds"] for f in exp.findings(_values(ap, fpr, f1=f1), better_synthesizer="spade")}[table4]


def test_identical_rows_are_detected_and_their_findings_untested():
    curves = lambda x: {"roc": (np.array([0, x, 1.0]), np.array([0, 0.5, 1])), "pr": (np.array([1, 0.5]), np.array([0.2, 0.4]))}
    a, b = exp.fingerprint(curves(0.2)), exp.fingerprint(curves(0.3))
    assert a != b and a == exp.fingerprint(curves(0.2))
    # identical in every seed -> grouped; identical in one seed only -> not
    seeds = [{"x": a, "y": a, "z": b, "w": a}, {"x": b, "y": b, "z": a, "w": a}]
    assert exp.identical_rows(seeds) == [["x", "y"]]
    assert exp.identical_rows(seeds[:1]) == [["x", "y", "w"]]
    # a claim comparing two identical rows is untested (never holds), the others keep their status
    ap, fpr, f1 = _favourable()
    got = {f["claim"]: f for f in exp.findings(_values(ap, fpr, f1=f1), identical=[[exp.ASSISTED, exp.BASE]])}
    untested = [c for c, f in got.items() if f["status"] == "untested"]
    assert untested == ["the assistant maps raise the resynthesis net's AP", "the assistant maps do not clearly lower FPR95",
                        "both together (MMF) have the best AP of the ablation",
                        "both together (MMF) have the best FPR95 of the ablation"]
    assert all(not got[c]["holds"] and got[c]["evidence"].startswith("untested: ") for c in untested)
    assert all(f["status"] == "holds" for c, f in got.items() if c not in untested)


class _FakePipe:
    """``MMFPipeline.maps`` of fixed random maps (no network): for ``_score``'s wiring."""

    def __init__(self, rng):
        self.rng = rng

    def maps(self, frames):
        b, (h, w) = len(frames), frames[0]["label"].shape
        maps = {name: self.rng.random((b, h, w)).astype(np.float32)
                for name in ("mmf", "resynthesis_score", "dissim_no_depth")}
        maps.update(logits=self.rng.normal(size=(b, h, w, 3)).astype(np.float32), num_segments=4,
                    superpixels=np.zeros((b, h, w), np.int32))
        self.last = maps
        return maps


def test_score_routes_each_row_to_its_net_with_auroc_and_mean_f1():
    from sklearn.metrics import roc_auc_score

    from jaxanom.metrics import component_metrics

    rng = np.random.default_rng(0)
    labels = rng.choice([0, 1], size=(3, 24, 40), p=[0.8, 0.2]).astype(np.uint8)
    labels[:, 8:20, 10:30] = 1  # one large obstacle per frame: components the obstacle track keeps
    roi = np.ones(labels.shape, bool)
    roi[:, :4] = False
    source = [{"label": l, "roi": r} for l, r in zip(labels, roi)]
    pipe = _FakePipe(rng)
    seen = []
    original = pipe.maps
    pipe.maps = lambda chunk: seen.append(original(chunk)) or seen[-1]
    rows = [exp.Row("a", "mmf_raw"), exp.Row("b", "mmf_raw", net="no_depth"), exp.Row("c", "resynthesis")]
    metrics, curves = exp._score(exp._maps(pipe, source, 2), rows, None)
    for label, key in (("a", "mmf"), ("b", "dissim_no_depth"), ("c", "resynthesis_score")):
        score = np.concatenate([m[key] for m in seen])
        scored = np.where(roi, labels, 255)
        keep = scored != 255
        assert np.isclose(metrics[label]["auroc"], roc_auc_score(scored[keep], score[keep]))
        expected = component_metrics(list(score), list(scored), track="obstacle")["f1_mean"]
        assert np.isclose(metrics[label]["components"]["f1_mean"], expected)
        row = exp._row_values(metrics[label], 0.5, "net", "mmf_raw")
        assert np.isclose(row["f1"], 100 * expected) and np.isclose(row["auroc"], 100 * metrics[label]["auroc"])
    assert len(seen) == 2  # the maps are computed once per batch, whatever the number of nets
    # each row's per-frame maps and counts for the paired bootstrap
    for label, key in (("a", "mmf"), ("b", "dissim_no_depth")):
        np.testing.assert_array_equal(np.stack(curves[label]["scores"]), np.concatenate([m[key] for m in seen]))
        np.testing.assert_array_equal(np.stack(curves[label]["labels"]), np.where(roi, labels, 255))
        counts = exp.frame_counts(metrics[label], curves[label])
        assert counts["histograms"].shape[0] == counts["components"].shape[0] == 3
        assert counts["histograms"].sum() == np.sum(roi)  # every non-void pixel of the ROI, once
        pooled = exp._pixel_metrics(counts["histograms"].sum(0))
        assert abs(pooled["auroc"] - 100 * metrics[label]["auroc"]) < 0.5
        pooled_f1 = exp._mean_f1(counts["components"].sum(0))["f1"]
        assert np.isclose(pooled_f1, 100 * metrics[label]["components"]["f1_mean"])


def test_mean_f1_of_pooled_counts_is_the_benchmarks():
    from jaxanom.metrics.components import component_summary

    rng = np.random.default_rng(1)
    frames = [(rng.random(int(rng.integers(0, 6))), rng.random(int(rng.integers(0, 6)))) for _ in range(7)]
    counts = np.array([[component_summary(s, p)[k] for k in ("tp", "fn", "fp")] for s, p in frames]).transpose(0, 2, 1)
    pooled = component_summary(np.concatenate([s for s, _ in frames]), np.concatenate([p for _, p in frames]))
    assert np.isclose(exp._mean_f1(counts.sum(0))["f1"], 100 * pooled["f1_mean"])
    assert np.isnan(exp._mean_f1(np.zeros((5, 3)))["f1"])  # no component at all: 0 / 0


def test_findings_use_the_paired_interval_when_rows_carry_replicates():
    ap, fpr, f1 = _favourable()
    values = _values(ap, fpr, std=100.0, f1=f1)  # a spread over seeds larger than every difference
    rng = np.random.default_rng(0)
    shared = {m: rng.normal(0.0, 30.0, 500) for m in ("ap", "fpr95", "auroc", "f1")}  # what the rows share
    for label, row in values.items():
        row["replicates"] = {m: row.get(m, 50.0) + shared[m] + rng.normal(0.0, 0.1, 500) for m in shared}
    got = {f["claim"]: f for f in exp.findings(values)}
    assert all(f["holds"] for f in got.values()), [c for c, f in got.items() if not f["holds"]]
    assert "Δ +20.00 [" in got["the assistant maps raise the resynthesis net's AP"]["evidence"]
    unpaired = {f["claim"]: f["holds"] for f in exp.findings(_values(ap, fpr, std=100.0, f1=f1))}
    assert [c for c, h in unpaired.items() if h] == ["the assistant maps do not clearly lower FPR95"]


@pytest.fixture
def untrained_parts(monkeypatch):
    """The pipeline's parts at random weights: every training call replaced by ``random_variables``."""

    def run_training(experiment, run_dir, **_):
        image = np.zeros((1, experiment.height, experiment.width, 3), np.float32)
        return random_variables(experiment.train.seed, functools.partial(build_network(experiment).init, train=False),
                                 image)

    def train(config, model, stream):
        batch = next(iter(stream))
        extras = {k: np.asarray(batch[k][:1]) for k in model.extra_inputs}
        variables = random_variables(config.seed, functools.partial(model.init, train=False),
                                      model_input(np.asarray(batch["image"][:1])), **extras)
        return types.SimpleNamespace(variables=variables)

    def train_gan(config, generator, critic, stream):
        label = np.asarray(next(iter(stream))["label"][:1])
        return types.SimpleNamespace(generator_variables=random_variables(config.seed, generator.init, label))

    monkeypatch.setattr(pipeline, "run_training", run_training)
    monkeypatch.setattr(pipeline, "train", train)
    monkeypatch.setattr(pipeline, "train_gan", train_gan)


@pytest.mark.end_to_end
def test_table_over_two_seeds_is_written_and_summarised(tmp_path, untrained_parts):
    out, runs = tmp_path / "out", tmp_path / "runs"
    exp.run(Scale.smoke(), 2, out, runs, log=lambda *_: None, description="MMF smoke.")
    assert sorted(p.name for p in out.iterdir()) == [f"{exp.NAME}{s}" for s in (".json", ".md", "_pr.png", "_roc.png")]
    saved = json.loads((out / f"{exp.NAME}.json").read_text())
    assert saved["num_seeds"] == 2 and saved["scale"]["height"] == 32 and saved["scale"]["width"] == 64
    # paired intervals over both seeds and their frames, for every metric the findings compare
    assert "paired difference (a bootstrap of 1000" in saved["seeds"] and saved["paired"]
    rows = {row["label"]: row for row in saved["table"]}
    assert all("replicates" not in row and len(row[f"{m}_interval"]) == 2 for row in rows.values()
               for m in ("ap", "fpr95", "auroc", "f1"))
    assert all(any(c["low"] is not None for c in f["intervals"]) for f in saved["findings"])
    assert list(rows) == [row.label for row in exp.ROWS]
    for spec in exp.ROWS:
        row = rows[spec.label]
        assert row["score"] == spec.method and len(row["ap_seeds"]) == 2
        for metric in ("ap", "fpr95", "auroc", "miou", "f1"):
            xs = np.array(row[f"{metric}_seeds"], float)
            assert all((0 <= x <= 100) or (metric == "f1" and np.isnan(x)) for x in xs)
            assert np.isclose(row[metric], np.mean(xs), equal_nan=True)
        # the two seeds are two pipelines: other networks, named by the part that scores the row
        first, second = row["networks"]
        part = "segmenter" if spec.method in {"entropy", "msp", "max_logit", "sml"} else "dissimilarity"
        assert first != second and first.split("-")[0] == part
    nets = {label: rows[label]["network"] for label in rows}
    assert nets[exp.BASE] == nets[exp.POST] and nets[exp.BASE] != nets[exp.ASSISTED]
    # every ablation net and the control are nets of their own, and none repeats another's outputs
    ablation = (exp.FULL, exp.NO_DEPTH, exp.NO_UNCERTAINTY, exp.BASE, exp.CONTROL, exp.SPADE_FULL, exp.SPADE_BASE)
    assert len({nets[label] for label in ablation}) == len(ablation)
    assert not [g for g in saved["identical_rows"] if len(set(g) & set(ablation)) > 1], saved["identical_rows"]
    assert set(saved["networks"]) >= {n for row in saved["table"] for n in row["networks"]}
    claims = exp.findings(result_values(saved), saved["identical_rows"],
                          "class_mean" if np.mean(saved["quality"]["class_mean_error"])
                          <= np.mean(saved["quality"]["spade_error"]) else "spade")
    saved_claims = saved["findings"] + saved["controls"]
    assert [(f["claim"], f["rows"]) for f in saved_claims] == [(c["claim"], c["rows"]) for c in claims]
    assert [c["control"] for c in saved["controls"]] == [True]
    for f in saved_claims:  # each verdict is its paired intervals' (only "do not clearly lower" asks for no gain)
        better = all(c["better"] for c in f["intervals"])
        verdict = better != ("do not" in f["claim"])
        assert f["holds"] == (f["status"] == "holds") == verdict or f["status"] == "untested"
    assert not any(f["control"] for f in saved["findings"])  # the control is not one of the paper's findings
    # a segmenter of random weights: nothing it feeds is a test of the paper (docs/decisions/baselines.md)
    assert all(f["tested"] is False and "% mIoU (< 60%)" in f["untested_because"] for f in claims)
    assert all(len(saved["quality"][k]) == 2 for k in ("segmenter_miou", "rgbd_miou", "rgbd_val_miou"))
    assert saved["description"].startswith("MMF smoke. Sizes: 32 x 64")
    table_text = (out / f"{exp.NAME}.md").read_text()  # each network's own step count, not one for all
    assert "training steps per network" not in table_text and "RGB-D net 2, SPADE GAN 2, every dissimilarity net 2" in table_text
    assert "SLIC step 1 px on the image" in saved["description"]  # scaled_step((32, 64)) = 1
    assert "RGB-D net mIoU" in table_text and "mean F1" in table_text and "OT 70.93 / 4.16 / 39.64" in table_text
    assert "| paper's finding | holds here? | tested? | evidence |" in table_text
    assert table_text.count("| **no**: the pipeline's segmenter reaches") == len(claims)  # each claim says why not
    text = write_results(out).read_text()
    assert exp.TITLE in text and "| MMF (assistant maps + post-processor) | `mmf` |" in text
    control = f"{int(saved['controls'][0]['holds'])} / 1"
    assert f"| 0 | 0 | {len(saved['findings'])} | {control} |" in text  # untested, and the control counted apart


def result_values(saved: dict) -> dict:
    return {row["label"]: row for row in saved["table"]}


@pytest.mark.end_to_end
def test_timed_modules_compute_the_pipelines_maps(tmp_path, untrained_parts):
    """``module_calls`` (Table 3's timings) times the computations ``MMFPipeline.maps`` makes."""
    from jaxanom.method_registry import score
    from jaxanom.data.synthetic import SyntheticScenes
    from jaxanom.models.dissimilarity import anomaly_probability

    config = pipeline.MMFConfig.quick()
    pipe = pipeline.MMFPipeline.build(config, tmp_path, progress=False, log=lambda *_: None)
    seg = config.segmenter
    frames = [SyntheticScenes("anomaly", 1, 0, height=seg.height, width=seg.width, disparity=True, roi=True)[0]]
    maps = pipe.maps(frames)
    calls = pipeline.module_calls(pipe, frames)
    assert list(calls) == ["segmentation", "uncertainty", "synthesis", "perceptual difference", "depth",
                           "dissimilarity", "post-processor"]
    close = lambda a, b: np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5)  # noqa: E731
    close(calls["segmentation"](), maps["logits"])
    close(calls["uncertainty"]()["entropy"], maps["entropy"])
    close(calls["synthesis"](), maps["resynthesis"])
    r, perceptual, anomaly = calls["perceptual difference"]()
    close(perceptual, maps["perceptual"]) or close(anomaly, maps["anomaly"])
    np.testing.assert_array_equal(np.argmax(np.asarray(calls["depth"]()), -1), maps["prediction_depth"])
    close(anomaly_probability(calls["dissimilarity"]()), maps["mmf"])
    batch = pipeline.scored_batch(frames, maps)
    close(calls["post-processor"](), score("mmf", {"logits": batch["logits"], "mmf_maps": batch["mmf_maps"]}))


def test_claims_reading_the_depth_semantics_need_a_competent_rgbd_net():
    ap, fpr, f1 = _favourable()
    values = _values(ap, fpr, f1=f1)
    for row in values.values():
        row["miou"] = 65.0  # a competent segmenter
    assert exp.DEPTH_ROWS == (exp.ASSISTED, exp.FULL, exp.NO_UNCERTAINTY, "MMF, connected superpixels",
                              "MMF, SLIC on the anomaly map a", exp.SPADE_FULL)
    competent = exp.findings(values, rgbd_miou=61.0)
    assert all(f["tested"] is True and f["untested_because"] == "" for f in competent)
    weak = {f["claim"]: f for f in exp.findings(values, rgbd_miou=21.0)}
    untested = [c for c, f in weak.items() if f["tested"] is False]
    assert untested == [c for c, f in weak.items() if set(f["rows"]) & set(exp.DEPTH_ROWS)]
    assert "Table 1: entropy beats the plain resynthesis net in AP" not in untested and len(untested) == 11
    assert all(weak[c]["untested_because"].startswith("the RGB-D net, whose semantics") for c in untested)
    # a weak segmenter fails every claim, with both reasons where both apply
    for row in values.values():
        row["miou"] = 30.0
    both = {f["claim"]: f for f in exp.findings(values, rgbd_miou=21.0)}
    assert all(f["tested"] is False for f in both.values())
    assert both[untested[0]]["untested_because"].count("mIoU (< 60%)") == 2


def test_rgbd_validation_miou_scores_the_depth_semantics_on_the_segmenters_validation_frames():
    from jaxanom.data import SyntheticScenes

    seg = pipeline.MMFConfig.quick().segmenter
    frames = SyntheticScenes("val", 5, seg.train.seed, height=seg.height, width=seg.width, disparity=True)
    labels = np.stack([frames[i]["label"] for i in range(5)]).astype(np.int64)

    class Pipe:  # predicts every class right except class 0, which it calls 1; Ŝ (unused) is garbage
        config = pipeline.MMFConfig.quick()

        def semantics(self, chunk):
            label = np.stack([f["label"] for f in chunk]).astype(np.int32)
            return -np.ones_like(label), np.where((label == 0) | (label == 255), 1, label)

    keep = labels != 255
    truth, guess = labels[keep], np.where(labels[keep] == 0, 1, labels[keep])
    ious = [np.sum((truth == c) & (guess == c)) / np.sum((truth == c) | (guess == c))
            for c in range(seg.num_classes) if np.any((truth == c) | (guess == c))]
    assert 0 in truth and exp.rgbd_validation_miou(Pipe(), 5) == pytest.approx(100 * np.mean(ious))
