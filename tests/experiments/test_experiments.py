"""The experiment runner (a seconds-long table) and the benchmark runner (fake modules)."""
import json
import math

import numpy as np
import pytest

from benchmarks.__main__ import NOTES, interpret
from benchmarks.__main__ import main as bench_main
from experiments.__main__ import summary, write_results
from experiments.common import (BASE_SCORES, Finding, Row, Scale, _scores, attention_positions, best, cudam,
                                improves, matched_sigma, matched_tau, ordered, run_table, scaled_logits, worse)


def test_matched_constants_keep_the_papers_per_pixel_magnitude():
    assert attention_positions(720, 720) == 180 * 180
    assert attention_positions(1024, 2048) == 256 * 512
    assert attention_positions(129, 257) == 33 * 65  # ceil at both stride-2 stages
    assert matched_tau(Scale(height=128, width=256)) == pytest.approx(5e4 * (32 * 64) / (180 * 180))
    assert matched_tau(Scale(height=720, width=720)) == pytest.approx(5e4)
    assert matched_sigma(1024, 2048) == pytest.approx(2e4)
    assert matched_sigma(128, 256) == pytest.approx(2e4 / 64)


def test_ensemble_scores_add_sigma_times_attention():
    rng = np.random.default_rng(0)
    logits = (rng.normal(size=(2, 9, 13, 5)) * 3).astype(np.float32)
    attention = rng.random((2, 9, 13)).astype(np.float32) / 30
    stats = (rng.normal(size=5).astype(np.float32), (0.5 + rng.random(5)).astype(np.float32))
    out = {"logits": logits, "attention_up": attention, "label": np.zeros((2, 9, 13), np.uint8)}
    scores = {k: np.asarray(v, np.float64) for k, v in _scores(out, stats).items()}
    sigma = 2e4 * (3 * 4) / (256 * 512)  # 9 x 13 frames -> 3 x 4 attention positions
    probabilities = np.exp(logits - logits.max(-1, keepdims=True))
    probabilities /= probabilities.sum(-1, keepdims=True)
    np.testing.assert_allclose(scores["msp+att"], 1 - probabilities.max(-1) + sigma * attention, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(scores["max_logit+att"], -logits.max(-1) + sigma * attention, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(scores["sml_post+att"], scores["sml_post"] + sigma * attention, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(scores["cudam"], scores["sml_post"] + 2e4 * attention, rtol=1e-5, atol=1e-4)
    plain = _scores({"logits": logits}, stats)
    assert tuple(plain) == BASE_SCORES


def test_findings_compare_in_the_right_direction():
    v = {"a": {"ap": 10.0, "fpr95": 50.0, "auroc": 80.0}, "b": {"ap": 20.0, "fpr95": 40.0, "auroc": 79.0}}
    assert improves(v, "b", "a", ("ap", "fpr95")).holds
    assert not improves(v, "b", "a", ("ap", "fpr95", "auroc")).holds
    assert not improves(v, "a", "b").holds
    assert worse(v, "a", "b", "fpr95", "claim").holds and not worse(v, "b", "a", "fpr95", "claim").holds
    assert ordered(v, ["a", "b"]).holds and not ordered(v, ["b", "a"]).holds
    assert best(v, "b", ["a", "b"], "fpr95").holds and best(v, "a", ["a", "b"], "auroc").holds
    assert "AP 20.00 vs 10.00" in improves(v, "b", "a").evidence


def test_scale_rejects_an_unknown_anomaly_reader():
    with pytest.raises(ValueError, match="anomaly"):
        Scale(anomaly="fishyscapes:/data")


@pytest.mark.end_to_end
def test_table_trains_once_evaluates_and_writes_results(tmp_path):
    scale = Scale.smoke()
    net = cudam(scale)
    control = scaled_logits(net)
    rows = [Row("SML", net, "sml_post"), Row("CuDAM + SML", net, "sml_post+att"), Row("MSP", net, "msp"),
            Row("scaled SML", control, "sml"), Row("scaled max logit", control, "max_logit")]

    def findings(v):
        return [improves(v, "CuDAM + SML", "SML"), Finding("always", True, "by construction")]

    def controls(v):
        return [improves(v, "scaled SML", "scaled max logit", claim="SML beats max logit on scaled logits")]

    out, runs = tmp_path / "out", tmp_path / "runs"
    result = run_table("smoke", "Smoke table", rows, findings, scale, out, runs, log=lambda *_: None,
                       description="What the smoke table shows.", controls=controls)

    # the control shares the trained network (one run folder), with an evaluation of its own
    assert control.run_key == net.run_key == net.key != control.key and control.to_dict()["class_scale"][0] == 0.25
    assert [p.name for p in runs.iterdir()] == [net.key]
    caches = sorted(p.name for p in (runs / net.key).glob("evaluation_*"))
    assert len(caches) == 4 and {p.rsplit(".", 1)[1] for p in caches} == {"json", "npz"}
    assert sorted(p.name for p in out.iterdir()) == ["smoke.json", "smoke.md", "smoke_pr.png", "smoke_roc.png"]
    saved = json.loads((out / "smoke.json").read_text())
    assert saved == json.loads(json.dumps(result))
    table = {row["label"]: row for row in saved["table"]}
    assert list(table) == ["SML", "CuDAM + SML", "MSP", "scaled SML", "scaled max logit"]
    for values in table.values():
        assert all(0 <= values[k] <= 100 and math.isfinite(values[k]) for k in ("ap", "auroc", "fpr95", "miou"))
        for k in ("ap", "auroc", "fpr95", "miou"):  # the interval of each row's metric
            assert len(values[f"{k}_interval"]) == 2 and values[f"{k}_interval"][0] <= values[f"{k}_interval"][1]
        assert 0 <= values["binning"] < 1  # binned metrics of all frames near the exact ones (points)
    assert table["SML"]["network"] == table["MSP"]["network"] == net.key and table["scaled SML"]["network"] == control.key
    assert saved["findings"][1] == {"claim": "always", "holds": True, "evidence": "by construction", "rows": [],
                                    "intervals": [], "tested": None, "untested_because": ""}
    first = saved["findings"][0]
    assert first["rows"] == ["CuDAM + SML", "SML"] and first["tested"] is False  # 2 training steps: mIoU far below 60
    assert first["intervals"][0]["low"] <= first["intervals"][0]["high"] and "Δ" in first["evidence"]
    assert saved["controls"][0]["claim"] == "SML beats max logit on scaled logits" and saved["paired"]
    assert "single seed" in saved["seeds"] and "95% interval of the paired difference" in saved["seeds"]
    markdown = (out / "smoke.md").read_text()
    assert markdown.startswith("## Smoke table\n\nWhat the smoke table shows. Run time: ")
    assert " min to train the table's networks (1 runs, from their logs" in saved["description"]
    assert "| CuDAM + SML | `sml_post+att` |" in markdown and "| always | yes | n/a | by construction |" in markdown
    assert "| positive control | passes? | evidence |" in markdown and "SML beats max logit on scaled logits" in markdown

    # Reading the cache changes nothing.
    stamps = {p: p.stat().st_mtime_ns for p in (runs / net.key).glob("evaluation_*")}
    run_table("smoke", "Smoke table", rows, findings, scale, out, runs, log=lambda *_: None, controls=controls)
    assert {p: p.stat().st_mtime_ns for p in (runs / net.key).glob("evaluation_*")} == stamps

    # A second table on the same network reads the cached evaluation (no new run folder).
    again = run_table("smoke2", "Again", rows[:1], lambda v: [], scale, out, runs, log=lambda *_: None)
    assert again["table"][0] == table["SML"]
    assert [p.name for p in runs.iterdir()] == [net.key]
    with pytest.raises(ValueError, match="not computed"):
        run_table("bad", "Bad", [Row("x", net, "entropy+att")], lambda v: [], scale, out, runs, log=lambda *_: None)

    # RESULTS.md gathers the known experiments' JSON files only.
    (out / "cudam_table2.json").write_text(json.dumps({**saved, "name": "cudam_table2"}))
    text = write_results(out).read_text()
    assert "Of 2 qualitative findings of the papers, 0 hold here, 0 fail, and 2 could not be tested" in text or (
        "Of 2 qualitative findings of the papers, 1 hold here, 0 fail, and 1 could not be tested" in text)
    assert "### CuDAM" in text and "Could not be tested here" in text and "mIoU below 60%" in text
    assert "Smoke table" in text and "single seed" in text.lower()
    assert "No experiment" in summary([])
    with_failure = summary([json.loads((out / "smoke.json").read_text())], {"cudam_fig6": "Traceback: boom"})
    assert "Smoke table" in with_failure and "## cudam_fig6: failed" in with_failure and "Traceback: boom" in with_failure


def test_an_evaluation_cache_without_its_frames_is_recomputed(tmp_path, monkeypatch):
    import experiments.common as common

    calls = []

    def fake_evaluate(net, variables, scale, log):
        calls.append(net.key)
        return {"miou": 0.5, "run": len(calls)}, {"confusion": np.full((2, 3, 3), len(calls))}

    monkeypatch.setattr(common, "evaluate", fake_evaluate)
    monkeypatch.setattr(common, "trained", lambda net, runs, log: {})
    net, scale = cudam(Scale.smoke()), Scale.smoke()
    result, arrays = common.evaluation(net, scale, tmp_path)
    assert result["run"] == 1 and (arrays["confusion"] == 1).all() and len(calls) == 1
    again, arrays = common.evaluation(net, scale, tmp_path)  # cached: not recomputed
    assert again == result and (arrays["confusion"] == 1).all() and len(calls) == 1
    [cache] = (tmp_path / net.run_key).glob("evaluation_*.json")
    cache.write_text(json.dumps({"miou": 0.5}))  # a cache from before the per-frame arrays
    assert common.evaluation(net, scale, tmp_path)[0]["run"] == 2
    cache.with_suffix(".npz").unlink()  # arrays lost
    assert common.evaluation(net, scale, tmp_path)[0]["run"] == 3
    cache.with_suffix(".npz").write_bytes(cache.with_suffix(".npz").read_bytes() + b"x")  # other arrays
    assert common.evaluation(net, scale, tmp_path)[0]["run"] == 4
    scaled, _ = common.evaluation(scaled_logits(net), scale, tmp_path)  # the control: its own cache, same folder
    assert scaled["run"] == 5 and calls[-1] == scaled_logits(net).key
    assert [p.name for p in tmp_path.iterdir()] == [net.run_key] and len(list(tmp_path.glob("*/*.npz"))) == 2
    assert not list(tmp_path.glob("*/.*"))  # no temporary file left


FAKE = '''
def run(quick=False):
    rows = [dict(benchmark="alpha", case="small", impl="jaxanom", median_ms=10.0, ratio=1.0),
            dict(benchmark="alpha", case="small", impl="peer", median_ms=20.0, ratio=2.0),
            dict(benchmark="alpha", case="big", impl="jaxanom", median_ms=100.0, ratio=1.0),
            dict(benchmark="alpha", case="big", impl="peer", median_ms=300.0, ratio=3.0, note="extra column")]
    return rows + [dict(benchmark="beta", case="q" if quick else "full", impl="jaxanom", median_ms=1.5)]
'''


def test_benchmark_runner_tables_and_results_file(tmp_path, capsys):
    (tmp_path / "bench_fake.py").write_text(FAKE)
    (tmp_path / "bench_broken.py").write_text("def run(quick=False):\n    raise RuntimeError('boom')\n")
    assert bench_main(["--quick", "--only", "fake", "--write"], directory=tmp_path) == 0
    text = (tmp_path / "RESULTS.md").read_text()
    assert "device:" in text and "jax " in text and "--quick" in text
    assert "### alpha" in text and "### beta" in text and "| q |" in text
    assert "| benchmark | case | impl | median_ms | ratio | note |" in text
    assert "peer takes 2x to 3x jaxanom's time (jaxanom faster)" in text
    assert "Reading: no peer in this run; 1.5 ms." in text
    assert "boom" not in text

    (tmp_path / "RESULTS.md").write_text(text + "GPU numbers from another machine.\n")
    assert bench_main(["--write"], directory=tmp_path) == 1
    text = (tmp_path / "RESULTS.md").read_text()
    assert "## bench_broken" in text and "failed" in text and "boom" in text and "| full |" in text
    assert text.endswith(NOTES + "\nGPU numbers from another machine.\n") and text.count(NOTES) == 1
    assert not list(tmp_path.glob(".RESULTS.md.*"))  # atomic write left no temporary file
    capsys.readouterr()


def test_benchmark_runner_writes_each_module_as_it_ends(tmp_path, capsys):
    """A run stopped at a time limit (here: interrupted in its second module) keeps the first."""
    (tmp_path / "bench_a_first.py").write_text(
        "def run(quick=False):\n    return [dict(benchmark='first', case='c', impl='jaxanom', median_ms=2.0)]\n")
    (tmp_path / "bench_b_killed.py").write_text("def run(quick=False):\n    raise KeyboardInterrupt\n")
    with pytest.raises(KeyboardInterrupt):
        bench_main(["--write"], directory=tmp_path)
    text = (tmp_path / "RESULTS.md").read_text()
    assert "## bench_a_first" in text and "| first | c | jaxanom | 2 |" in text and "b_killed" not in text
    capsys.readouterr()


def test_interpret_mixed_and_slower_peers():
    rows = [dict(case="a", impl="jaxanom", median_ms=10.0), dict(case="a", impl="torch", median_ms=5.0),
            dict(case="b", impl="jaxanom", median_ms=10.0), dict(case="b", impl="torch", median_ms=20.0),
            dict(case="b", impl="sk", median_ms=4.0)]
    assert interpret(rows) == ("torch takes 0.5x to 2x jaxanom's time (jaxanom faster in some cases, slower in "
                               "others); sk takes 0.4x jaxanom's time (jaxanom slower).")


def test_benchmark_runner_reports_a_missing_library_and_writes_where_told(tmp_path, capsys):
    (tmp_path / "bench_needs.py").write_text(
        "from benchmarks.timing import require\n\ndef run(quick=False):\n"
        "    require('no_such_library_xyz')\n    return []\n")
    results = tmp_path / "elsewhere" / "GPU.md"
    results.parent.mkdir()
    assert bench_main(["--write", "--results", str(results)], directory=tmp_path) == 0
    text = results.read_text()
    assert "## bench_needs" in text and "not run: no_such_library_xyz is not installed on this machine" in text
    assert not (tmp_path / "RESULTS.md").exists()
    capsys.readouterr()


def test_benchmark_helpers_bandwidth_and_cpu_check():
    from benchmarks.timing import gb_per_s, same_as_cpu

    assert gb_per_s(3 * 10**9, 1000.0) == "3 GB/s"
    assert same_as_cpu(lambda: 1 / 0, 0.0) == ""  # on a CPU nothing is recomputed


def test_seeds_aggregate_to_mean_and_sample_std_and_findings_need_the_spread():
    from experiments.common import aggregate, seed_scales

    per_seed = [{"a": {"ap": ap, "auroc": 80.0, "fpr95": f, "miou": 50.0, "network": f"n{i}", "score": "msp"},
                 "b": {"ap": 10.0 + i, "auroc": 80.0, "fpr95": 40.0, "miou": 50.0, "network": f"m{i}", "score": "sml"}}
                for i, (ap, f) in enumerate([(12.0, 50.0), (14.0, 52.0), (16.0, 60.0)])]
    v = aggregate(per_seed)
    assert v["a"]["ap"] == pytest.approx(14.0) and v["a"]["ap_std"] == pytest.approx(np.std([12, 14, 16], ddof=1))
    assert v["a"]["ap_seeds"] == [12.0, 14.0, 16.0] and v["a"]["networks"] == ["n0", "n1", "n2"]
    # AP: a 14 +- 2 vs b 11 +- 1: the difference 3 exceeds the larger std 2
    assert improves(v, "a", "b").holds and "14.00 ± 2.00" in improves(v, "a", "b").evidence
    # FPR95: b 40 +- 0 vs a 54 +- 5.3: holds; AUROC equal: does not
    assert improves(v, "b", "a", ("fpr95",)).holds and not improves(v, "b", "a", ("auroc",)).holds
    per_seed[2]["a"]["ap"] = 30.0  # a 18.7 +- 9.5 vs b 11: within the spread
    assert not improves(aggregate(per_seed), "a", "b").holds
    assert [s.seed for s in seed_scales(Scale(seed=4), 3)] == [4, 5, 6]
    with pytest.raises(ValueError, match="seeds"):
        seed_scales(Scale(), 0)


def test_command_line_sets_the_scale():
    from experiments.__main__ import parse_args, scale_from

    scale = scale_from(parse_args(["--size", "64", "128", "--train-frames", "128", "--steps", "300"]))
    assert (scale.height, scale.width, scale.train_frames, scale.steps) == (64, 128, 128, 300)
    assert scale_from(parse_args([])) == Scale()


def test_benchmark_peak_memory_is_the_childs_own_not_its_parents():
    from benchmarks.bench_score_memory import _peak_of

    ballast = np.ones(300 * 2**20 // 8)  # the parent grows by 300 MB before starting the children
    small, _ = _peak_of("pass")
    large, _ = _peak_of("import numpy; x = numpy.ones(400 * 2**20 // 8)")
    assert small < 150 < 350 + small < large
    del ballast
