"""Paired intervals of the paper tables (experiments/common.py, experiments/stats.py) against a direct
NumPy / scikit-learn bootstrap written here, and the positive control of SML's logit scales."""
import numpy as np
import pytest
from sklearn.metrics import average_precision_score, roc_auc_score, roc_curve

from experiments.common import (COMPETENT_MIOU, Scale, _scaled, _scores, control_scales, improves, not_better,
                                oracle_attention, paired_replicates)
from experiments.stats import binned_auroc, bootstrap, frame_histograms, hierarchical_draws, interval

EDGES = np.arange(0, 30) + 0.5  # integer scores 0..29, one per bin: binned metrics are exact
CLASSES = 4


def synthetic_seed(rng, frames: int, shift: float, val_frames: int = 3):
    """One seed of one row: (scores, labels) per anomaly frame (integer scores, ties, void) and
    (V, C, C) confusion matrices of validation frames."""
    scores, labels = [], []
    for f in range(frames):
        size = int(rng.integers(20, 60))
        label = (rng.random(size) < 0.3).astype(np.uint8)
        label[rng.random(size) < 0.1] = 255
        label[0], label[1] = 0, 1  # every frame has both classes
        score = np.clip(rng.integers(0, 20, size) + shift * (label == 1), 0, 29).astype(np.float32)
        scores.append(score)
        labels.append(label)
    confusion = rng.integers(0, 30, (val_frames, CLASSES, CLASSES))
    confusion[:, 3, :] = 0  # class 3 never occurs ...
    confusion[1:, :, 3] = 0  # ... and is predicted in one frame only
    return scores, labels, confusion


@pytest.fixture(scope="module")
def rows():
    """Two rows x 3 seeds of raw frames (5, 4 and 6 anomaly frames; 3 validation frames), row "b" better."""
    rng = np.random.default_rng(0)
    return {name: [synthetic_seed(rng, frames, shift) for frames in (5, 4, 6)] for name, shift in (("a", 2), ("b", 6))}


def as_frames(rows):
    """``paired_replicates``' input: per seed, per row, histograms and confusion matrices."""
    return [{name: {"histograms": frame_histograms(seeds[s][0], seeds[s][1], EDGES), "confusion": seeds[s][2]}
             for name, seeds in rows.items()} for s in range(3)]


def reference(seeds, draws) -> dict:
    """The hierarchical bootstrap written directly: every drawn frame's pixels repeated by its multiplicity,
    metrics by scikit-learn, mIoU from the summed confusion matrix by hand, averaged over the slots."""
    out = {"ap": [], "fpr95": [], "auroc": [], "miou": []}
    for r in range(draws.seeds.shape[0]):
        slots = {k: [] for k in out}
        for k, s in enumerate(draws.seeds[r]):
            scores, labels, confusion = seeds[s]
            times = draws.frames["anomaly"][r, k]
            x = np.concatenate([np.repeat(scores[f], times[f]) for f in range(len(scores))])
            y = np.concatenate([np.repeat(labels[f], times[f]) for f in range(len(scores))])
            x, y = x[y != 255], y[y != 255]
            fpr, tpr, _ = roc_curve(y, x)
            slots["ap"].append(100 * average_precision_score(y, x))
            slots["fpr95"].append(100 * fpr[np.argmax(tpr >= 0.95)])
            slots["auroc"].append(100 * roc_auc_score(y, x))
            m = sum(confusion[v] * draws.frames["val"][r, k, v] for v in range(len(confusion))).astype(float)
            union = m.sum(0) + m.sum(1) - np.diag(m)
            slots["miou"].append(100 * np.mean(np.diag(m)[union > 0] / union[union > 0]))
        for k in out:
            out[k].append(np.mean(slots[k]))
    return {k: np.array(v) for k, v in out.items()}


def test_paired_replicates_and_intervals_match_a_direct_bootstrap(rows):
    got = paired_replicates(as_frames(rows), replicates=40, seed=5)
    draws = hierarchical_draws({"anomaly": [5, 4, 6], "val": [3, 3, 3]}, 40, 5)
    want = {name: reference(seeds, draws) for name, seeds in rows.items()}
    for name in rows:
        for metric in ("ap", "fpr95", "auroc", "miou"):
            np.testing.assert_allclose(got[name][metric], want[name][metric], rtol=1e-10, atol=1e-10)
    for metric in ("ap", "fpr95", "auroc", "miou"):
        low, high = np.percentile(want["b"][metric] - want["a"][metric], [2.5, 97.5])
        assert interval(got["b"][metric] - got["a"][metric]) == pytest.approx((low, high), abs=1e-9)


def test_identical_rows_differ_by_exactly_zero_and_every_row_gets_the_same_draws(rows):
    frames = as_frames({"a": rows["a"], "a again": rows["a"], "b": rows["b"]})
    got = paired_replicates(frames, replicates=200)
    for metric in ("ap", "fpr95", "auroc", "miou"):
        assert interval(got["a again"][metric] - got["a"][metric]) == (0.0, 0.0)
        assert np.std(got["a"][metric]) > 0  # the replicates do vary
    # the draws do not depend on the rows (order or set): a row's replicates are the same in any table
    alone = paired_replicates([{"b": f["b"]} for f in frames], replicates=200)
    np.testing.assert_array_equal(alone["b"]["ap"], got["b"]["ap"])
    assert paired_replicates(frames, replicates=200)["a"]["ap"].tolist() == got["a"]["ap"].tolist()  # deterministic


def test_one_seed_is_the_bootstrap_over_frames(rows):
    frames = as_frames(rows)[:1]
    got = paired_replicates(frames, replicates=50, seed=3)
    draws = hierarchical_draws({"anomaly": [5], "val": [3]}, 50, 3)
    assert (draws.seeds == 0).all()
    want = bootstrap(frames[0]["a"]["histograms"], draws.frames["anomaly"][:, 0])
    np.testing.assert_allclose(got["a"]["ap"], 100 * want["ap"], rtol=1e-12)
    np.testing.assert_allclose(got["a"]["fpr95"], 100 * want["fpr_at_tpr"], rtol=1e-12)


def values_of(rows, replicates=300):
    """Table values with replicates, means from the exact metrics (as ``run_table`` builds them)."""
    got = paired_replicates(as_frames(rows), replicates=replicates)
    return {name: {**{m: float(np.mean(r)) for m, r in got[name].items()}, "replicates": got[name]} for name in got}


def test_a_clearly_better_row_is_found_better_and_a_tie_is_not(rows):
    v = values_of({"a": rows["a"], "b": rows["b"], "a again": rows["a"]})
    better = improves(v, "b", "a", ("ap", "fpr95", "auroc"))
    assert better.holds and better.rows == ["b", "a"]
    assert [c["metric"] for c in better.intervals] == ["ap", "fpr95", "auroc"]
    ap, fpr = better.intervals[0], better.intervals[1]
    assert ap["low"] > 0 and fpr["high"] < 0 and ap["difference"] == pytest.approx(v["b"]["ap"] - v["a"]["ap"])
    assert f"Δ {ap['difference']:+.2f} [{ap['low']:+.2f}, {ap['high']:+.2f}]" in better.evidence
    assert not improves(v, "a", "b").holds and not improves(v, "a again", "a").holds
    assert not_better(v, "a again", "a", "ap", "tie").holds and not not_better(v, "b", "a", "ap", "x").holds
    assert "[+0.00, +0.00]" in improves(v, "a again", "a").evidence


def test_competence_flags_findings_on_networks_below_the_bar():
    v = {"weak": {"ap": 20.0, "miou": COMPETENT_MIOU - 0.1, "network": "n1"},
         "strong": {"ap": 10.0, "miou": COMPETENT_MIOU, "network": "n2"},
         "strong 2": {"ap": 5.0, "miou": 80.0, "network": "n3"}}
    assert improves(v, "strong", "strong 2").tested is True
    weak = improves(v, "weak", "strong")
    assert weak.tested is False and weak.untested_because == "mIoU below 60%: weak (`n1`) 59.9"
    assert improves({"x": {"ap": 1.0}, "y": {"ap": 0.0}}, "x", "y").tested is None


def test_rows_on_different_frames_are_refused(rows):
    frames = as_frames(rows)
    frames[1]["b"] = {**frames[1]["b"], "histograms": frames[1]["b"]["histograms"][:2]}
    with pytest.raises(ValueError, match="different anomaly frames"):
        paired_replicates(frames, replicates=5)


def test_hierarchical_draws_resample_seeds_then_their_frames():
    draws = hierarchical_draws({"anomaly": [3, 7], "val": [2, 2]}, replicates=4000, seed=1)
    assert draws.seeds.shape == (4000, 2) and set(np.unique(draws.seeds)) == {0, 1}
    frames = draws.frames["anomaly"]
    counts = np.array([3, 7])[draws.seeds]
    np.testing.assert_array_equal(frames.sum(-1), counts)  # each slot draws as many frames as its seed has
    assert (frames[draws.seeds == 0][:, 3:] == 0).all()  # nothing beyond seed 0's three frames
    assert np.mean(draws.seeds) == pytest.approx(0.5, abs=0.03)
    assert frames[draws.seeds == 1].mean(0) == pytest.approx(np.ones(7), abs=0.05)  # each frame drawn once on average
    np.testing.assert_array_equal(draws.frames["val"].sum(-1), 2)
    again = hierarchical_draws({"anomaly": [3, 7], "val": [2, 2]}, replicates=4000, seed=1)
    np.testing.assert_array_equal(again.frames["anomaly"], frames)
    for bad in ({"anomaly": [3, 7], "val": [2]}, {"anomaly": [3, 0]}, {"anomaly": []}):
        with pytest.raises(ValueError, match="counts"):
            hierarchical_draws(bad, 5)


def test_binned_auroc_with_one_bin_per_score_is_scikit_learns(rows):
    scores, labels, _ = rows["a"][0]
    keep = np.concatenate(labels) != 255
    histograms = frame_histograms(scores, labels, EDGES).sum(0)
    want = roc_auc_score(np.concatenate(labels)[keep], np.concatenate(scores)[keep])
    assert binned_auroc(histograms) == pytest.approx(want, rel=1e-12)


# ---------------------------------------------------------------- SML's positive control


def control_frames(seed: int, scale: bool = True):
    """Logits of a network that knows its classes: in-distribution pixels peak at their class (about 6),
    anomalies (label 1) are unsure (peak about 3); then (``scale``) each pixel's logits times its
    predicted class's factor of ``control_scales``."""
    rng = np.random.default_rng(seed)
    classes = rng.integers(0, CLASSES, (4, 16, 16))
    anomaly = rng.random((4, 16, 16)) < 0.1
    logits = rng.normal(0, 1, (4, 16, 16, CLASSES)).astype(np.float32)
    peak = np.where(anomaly, 3.0, 6.0) + rng.normal(0, 0.7, anomaly.shape)
    np.put_along_axis(logits, classes[..., None], peak[..., None].astype(np.float32), -1)
    if scale:
        logits = _scaled(lambda images: {"logits": logits}, control_scales(CLASSES))(None)["logits"]
    return logits, anomaly.astype(np.uint8)


def control_values(broken: bool) -> dict:
    from jaxanom import sml

    per_seed = []
    for seed in range(2):
        logits, labels = control_frames(seed)
        stats = sml.stats_finalize(sml.fit_stats([control_frames(10 + seed)[0]]), missing="pooled", policy="none")
        if broken:  # SML's normalisation ignored: mean 0, std 1 for every class
            stats = (np.zeros_like(np.asarray(stats[0])), np.ones_like(np.asarray(stats[1])))
        scores = _scores({"logits": logits}, stats)
        edges = np.unique(np.quantile(np.concatenate([np.asarray(scores[k]).ravel() for k in ("sml", "max_logit")]),
                                      np.linspace(0, 1, 513)[1:-1]))
        per_seed.append({k: {"histograms": frame_histograms(list(np.asarray(scores[k])), list(labels), edges),
                             "confusion": np.ones((1, CLASSES, CLASSES), np.int64)} for k in ("sml", "max_logit")})
    replicates = paired_replicates(per_seed, replicates=300)
    return {k: {**{m: float(np.mean(r)) for m, r in replicates[k].items()}, "replicates": replicates[k]}
            for k in replicates}


def test_the_scaled_logit_control_passes_with_sml_and_fails_when_its_normalisation_is_ignored():
    scales = control_scales(19)
    assert len(scales) == 19 and scales[0] == pytest.approx(0.25) and scales[-1] == pytest.approx(4.0)
    assert np.allclose(np.diff(np.log(scales)), np.log(16) / 18)  # a geometric spread
    logits = np.random.default_rng(1).normal(size=(2, 3, 5, CLASSES)).astype(np.float32)
    got = _scaled(lambda x: {"logits": logits, "other": 1}, [1, 2, 3, 4])(None)
    want = np.empty_like(logits)
    for index in np.ndindex(logits.shape[:-1]):  # each pixel times its predicted class's factor
        want[index] = logits[index] * [1, 2, 3, 4][int(np.argmax(logits[index]))]
    np.testing.assert_allclose(got["logits"], want, rtol=1e-6)
    assert got["other"] == 1
    # predictions kept; SML refitted on the scaled logits is SML of the original ones
    scaled, labels = control_frames(0)
    original = control_frames(0, scale=False)[0]
    assert (np.argmax(scaled, -1) == np.argmax(original, -1)).all()
    from jaxanom import sml

    def sml_of(x):
        stats = sml.stats_finalize(sml.fit_stats([x]), missing="pooled", policy="none")
        return np.asarray(_scores({"logits": x}, stats)["sml"])

    np.testing.assert_allclose(sml_of(scaled), sml_of(original), rtol=1e-4, atol=1e-4)
    good = improves(control_values(broken=False), "sml", "max_logit")
    assert good.holds and good.intervals[0]["low"] > 5  # by points of AP
    broken = improves(control_values(broken=True), "sml", "max_logit")
    assert not broken.holds and broken.intervals[0]["high"] == pytest.approx(0.0, abs=1e-9)


def test_the_oracle_attention_spends_a_real_maps_mass_on_the_anomalies_only():
    labels = np.zeros((3, 5, 7), np.uint8)
    labels[0, 1:3, 2:5] = 1                 # 6 of 35 pixels
    labels[0, 4, :] = 255                   # void is not anomaly
    labels[1, :, :] = 255                   # no anomaly at all: uniform
    labels[2, 0, 0] = 1                     # one pixel
    att = oracle_attention(labels, positions=12)
    assert att.dtype == np.float32 and att.shape == labels.shape
    np.testing.assert_allclose(att[0][labels[0] == 1], 35 / (6 * 12), rtol=1e-6)
    assert (att[0][labels[0] != 1] == 0).all()
    np.testing.assert_allclose(att[1], 1 / 12, rtol=1e-6)
    np.testing.assert_allclose(att[2, 0, 0], 35 / 12, rtol=1e-6)
    np.testing.assert_allclose(att.mean(axis=(1, 2)), 1 / 12, rtol=1e-6)  # a real upsampled map's mean
    # Eq. 10 with it at the matched sigma: the control score of a network with attention
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(3, 5, 7, CLASSES)).astype(np.float32)
    from jaxanom import sml
    from jaxanom.cudam.score import paper_sigma

    stats = sml.stats_finalize(sml.fit_stats([logits]), missing="pooled", policy="none")
    out = {"logits": logits, "label": labels, "attention_up": np.full(labels.shape, 1 / 12, np.float32),
           "attention_positions": 12}
    scores = _scores(out, stats)
    np.testing.assert_allclose(scores["sml_post+oracle"], np.asarray(scores["sml_post"]) + paper_sigma(12) * att,
                               rtol=1e-5, atol=1e-5)


def test_summary_lists_per_paper_what_holds_what_fails_and_what_could_not_be_tested():
    from experiments.__main__ import summary

    def finding(claim, holds, tested, why="", low=1.0):
        return {"claim": claim, "holds": holds, "evidence": f"evidence of {claim}", "rows": ["x", "y"],
                "intervals": [{"a": "x", "b": "y", "metric": "ap", "difference": 1.0, "low": low, "high": 2.0,
                               "better": holds}], "tested": tested, "untested_because": why}

    def result(name, findings, controls=()):
        return {"name": name, "title": name.upper(), "description": "", "table": [], "scale": Scale().__dict__,
                "findings": findings, "controls": list(controls), "networks": {}, "seeds": "s", "num_seeds": 3,
                "paired": True}

    results = [result("sml_a", [finding("sml holds", True, True), finding("sml fails", False, True),
                                finding("sml weak", True, False, "mIoU below 60%: `n1` 18.0")]),
               result("cudam_b", [finding("cudam good", True, True), finding("cudam weak", True, False, "low mIoU")],
                      [finding("control", False, True)]),
               {"name": "offroad_c", "title": "OFF", "scale": Scale().__dict__, "report": "## OFF",
                "findings": [{"claim": "offroad claim", "holds": True, "evidence": "e"}]}]
    text = summary(results)
    assert "Of 6 qualitative findings of the papers, 2 hold here, 1 fail, and 3 could not be tested" in text
    sml = text[text.index("### SML"):text.index("### CuDAM")]
    holds, fails, untested = (sml[sml.index(h):] for h in ("Holds", "Fails in a competent", "Could not be tested"))
    assert "sml holds (evidence of sml holds)" in holds.split("Fails")[0] and "sml fails" not in holds.split("Fails")[0]
    assert "sml fails (evidence of sml fails)" in fails.split("Could not")[0]
    assert "sml weak — mIoU below 60%: `n1` 18.0" in untested and "evidence of sml weak" not in untested
    cudam = text[text.index("### CuDAM"):text.index("### off-road")]
    assert "cudam good — the table's positive control failed (points at a bug): control" in cudam
    assert "cudam weak — low mIoU; the table's positive control failed" in cudam  # both reasons
    assert "Holds" in cudam and cudam.count("- none") == 2
    offroad = text[text.index("### off-road"):text.index("## Tables")]
    assert "offroad claim (e) — no paired interval" in offroad and "no segmenter mIoU" in offroad
    assert "| [CUDAM_B](#cudam_b) | 0 | 0 | 2 | 0 / 1 |" in text and "| [OFF](#off) | 1 | 0 | 0 | none yet |" in text
    # a table written before the mIoU bar (its findings carry no "tested"): judged by its rows' mIoU
    old = {"name": "msaam_old", "title": "OLD", "description": "", "scale": Scale().__dict__, "seeds": "s",
           "num_seeds": 3, "networks": {}, "table": [{"label": k, "score": "sml", "network": "n", "miou": m, "ap": 1.0, "fpr95": 1.0, "auroc": 1.0}
                     for k, m in (("x", 18.3), ("y", 61.0))],
           "findings": [{"claim": "old claim", "holds": False, "evidence": "e"}]}
    text = summary([old])
    assert "old claim — its networks reach 18.3% mIoU at the lowest (< 60%)" in text
    assert "and 1 could not be tested" in text


def test_training_minutes_sum_the_logged_steps_and_leave_out_restarts(tmp_path):
    import json

    from experiments.common import training_minutes

    def write(key, records):
        (tmp_path / key).mkdir()
        (tmp_path / key / "log.jsonl").write_text("".join(json.dumps({"step": s, "time": t}) + "\n" for s, t in records))

    write("a", [(1, 100.0), (2, 130.0), (3, 160.0)])  # 60 s
    write("b", [(1, 0.0), (2, 60.0), (1, 5000.0), (2, 5030.0), (3, 5090.0)])  # killed after step 2, rerun: 150 s
    assert training_minutes(tmp_path, ["a", "b", "a"]) == pytest.approx(210 / 60)
    assert training_minutes(tmp_path, []) == 0.0
    assert training_minutes(tmp_path, ["a", "missing"]) is None
    write("empty", [])
    assert training_minutes(tmp_path, ["empty"]) is None
