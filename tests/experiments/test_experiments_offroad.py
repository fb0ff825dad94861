"""The off-road experiments: a seconds-long smoke run of all three, and their findings on hand-made values."""
import json
import math

import numpy as np
import pytest

from experiments import offroad_exp2, offroad_table2, offroad_table3
from experiments.__main__ import summary
from experiments.common import Scale
from experiments.offroad_common import OffroadSizes, offroad_sizes, paired_replicates, per_seed


@pytest.mark.end_to_end
def test_smoke_run_writes_tables_that_the_summary_includes(tmp_path):
    out, runs, quiet = tmp_path / "out", tmp_path / "runs", (lambda *_: None)
    results = [module.run(Scale.smoke(), 1, out, runs, log=quiet, description=f"{module.NAME} text.")
               for module in (offroad_exp2, offroad_table2, offroad_table3)]
    assert sorted(p.name for p in out.iterdir()) == sorted(f"{r['name']}.{ext}" for r in results for ext in ("json", "md"))
    for result in results:
        saved = json.loads((out / f"{result['name']}.json").read_text())
        assert saved == json.loads(json.dumps(result)) and saved["num_seeds"] == 1
        assert saved["findings"] and all(f["evidence"] for f in saved["findings"])
        assert (out / f"{result['name']}.md").read_text() == saved["report"] + "\n"
        assert saved["report"].startswith(f"## {saved['title']}\n\n{saved['name']} text. Run time: ")
        assert " min to compute its seeds" in saved["report"].splitlines()[2]
    # Exp. 2 counts clusters per seed (no frames): no paired interval, no mIoU bar, none invented.
    assert all(f["intervals"] == [] and f["tested"] is None for f in results[0]["findings"]) and not results[0]["paired"]
    for result in results[1:]:  # Tables II and III: every comparison paired, untested only where saturated
        assert result["paired"] and all(f["intervals"] for f in result["findings"])
        assert all(f["tested"] is None or (f["tested"] is False and ("saturated" in f["untested_because"] or
                                                                     "does not rank" in f["untested_because"]))
                   for f in result["findings"])
    assert all(f["holds"] == all(c["better"] for c in f["intervals"]) for f in results[1]["findings"])  # verdicts
    assert all(f"{m}_interval" in row for row in results[2]["table"] for m in ("pa", "iou", "pre", "rec", "fpr"))
    exp2, table2, table3 = ({row["label"]: row for row in r["table"]} for r in results)
    assert list(exp2) == ["LV1", "LV2", "LV3", offroad_exp2.CONTROL, offroad_exp2.REFERENCE]
    assert [exp2[k]["classes"] for k in exp2] == [4, 6, 10, 3, 3]
    assert all(row["clusters"] in (2, 3) and 1 <= row["recovered"] <= row["clusters"] for row in exp2.values())
    # Every table has its positive control, and it passes at smoke sizes too (it holds by construction).
    assert [[c["holds"] for c in r["controls"]] for r in results] == [[True], [True], [True]]
    assert all("| positive control | passes? |" in r["report"] for r in results)
    sizes = offroad_sizes(Scale.smoke())
    assert list(table2) == ["M_A", "Rand B2", "Unif B2", "Ours B1", "Ours B2", "Ours B2 + triggered round",
                            "control: Oracle B2"]
    for label, row in table2.items():
        assert all(0 <= row[k] <= 100 for k in ("mflr_b", "mflr_c", "sc_b", "sc_c", "pa_b", "pa_c", "miou_b", "miou_c",
                                                "phi_b", "error"))
        if "+" in label:  # the second round's frames join the first's (it ran only if the trigger fired)
            assert row["rounds"] in (1, 2) and 2 <= len(row["frames"]) <= 2 * row["rounds"]
            continue
        assert len(row["frames"]) == (0 if label == "M_A" else int(label[-1]))
        assert all(b - a > sizes.gap for a, b in zip(row["frames"], row["frames"][1:])) or label.startswith("Unif")
    assert list(table3)[:3] == ["5-class M_A", "5-class M_A known argmax", "5-class M_A + CRF"] and len(table3) == 28
    supervised = [k for k in table3 if "supervised" in k]
    assert supervised == [f"{c}-class supervised D{b} (paper D{p}){r}" for c in (5, 4) for b, p in ((1, 20), (2, 40))
                          for r in ("", " + CRF")]
    assert list(table3)[-2:] == [offroad_table3.CONTROL_NOISY, offroad_table3.CONTROL_CRF]
    for label, row in table3.items():
        assert 0 <= row["pa"] <= 100 and 0 <= row["iou"] <= 100 and math.isfinite(row["iou"])
        assert all(0 <= row[k] <= 100 or math.isnan(row[k]) for k in ("pre", "rec", "fpr"))
        if label in supervised or label.startswith("control"):  # a supervised row's m: its classes
            assert row["clusters"] == int(label[0]) if label in supervised else row["clusters"] == 5
            continue
        assert row["clusters"] == 5 if label.startswith("5-class") else row["clusters"] in (2, 3)
    # Supervised rows train on the frames their budget's active rows annotate.
    assert all(table3[k]["frames"] == table3[k.replace("supervised ", "").removesuffix(" + CRF")]["frames"]
               for k in supervised)
    # The summary renders each experiment's own table (no ROC/PR curve lines for them).
    text = summary([json.loads((out / f"{r['name']}.json").read_text()) for r in results])
    assert all(r["report"] in text for r in results) and "offroad_exp2_roc.png" not in text
    per_paper = text[text.index("### off-road"):text.index("## Tables")]
    exp2_lines = [line for line in per_paper.splitlines() if line.startswith("- `offroad_exp2`")]
    assert exp2_lines and all("no paired interval" in line and "Δ" not in line for line in exp2_lines)
    decided = per_paper[:per_paper.index("Could not be tested here")]  # untested lines give no evidence
    paired_lines = [line for line in decided.splitlines() if line.startswith(("- `offroad_table2`", "- `offroad_table3`"))]
    assert paired_lines and all("Δ" in line and "no paired interval" not in line for line in paired_lines)
    rows = [next(line for line in text.splitlines() if line.startswith(f"| [{r['title']}]")) for r in results]
    assert all(line.endswith("| 1 / 1 |") for line in rows)  # the summary counts their controls
    # A rerun reads every seed's values from the cache: same tables, nothing recomputed.
    again = offroad_table2.run(Scale.smoke(), 1, tmp_path / "again", runs, log=quiet)
    assert json.dumps(again["table"]) == json.dumps(results[1]["table"])  # NaN (a constant FLR's rho) equal too


def test_per_seed_values_are_cached_by_sizes(tmp_path):
    calls = []
    sizes = offroad_sizes(Scale.smoke())
    compute = lambda: calls.append(1) or {"row": {"x": 1.0, "network": "n"}}  # noqa: E731
    assert per_seed("t", sizes, tmp_path, compute, log=lambda *_: None) == {"row": {"x": 1.0, "network": "n"}}
    assert per_seed("t", sizes, tmp_path, compute, log=lambda *_: None) == {"row": {"x": 1.0, "network": "n"}}
    other = OffroadSizes(sizes.demo, active_frames=6)
    per_seed("t", other, tmp_path, compute, log=lambda *_: None)
    assert len(calls) == 2  # once per distinct sizes
    assert offroad_sizes(Scale()).demo.pipeline.components == tuple(range(2, 13)) and not offroad_sizes(Scale()).smoke


def _rows(**means):
    """Aggregated rows {label: {metric: mean, metric_std: std}} from {label: {metric: (mean, std)}}."""
    return {label: {k: v for metric, (m, s) in row.items() for k, v in ((metric, m), (f"{metric}_std", s))}
            for label, row in means.items()}


def test_findings_need_the_difference_to_exceed_the_spread():
    exp2 = _rows(LV1={"clusters": (4.0, 0.0), "classes": (4, 0)}, LV2={"clusters": (6.0, 0.5), "classes": (6, 0)},
                 LV3={"clusters": (9.0, 0.5), "classes": (10, 0)})
    for row in exp2.values():
        row["clusters_seeds"] = [row["clusters"]] * 3
    assert [f.holds for f in offroad_exp2.findings(exp2)] == [True, True, True, True]
    exp2["LV2"]["clusters_std"] = 2.5  # 6 -> 9 by 3 > 2.5 still, but 4 -> 6 by 2 < 2.5
    assert not offroad_exp2.findings(exp2)[0].holds

    good = {"M_A": (60, 10, 5), "Rand B4": (50, 40, 4), "Unif B4": (45, 60, 2), "Ours B2": (48, 50, 1),
            "Ours B4": (40, 80, 1), "Ours B8": (35, 90, 1)}
    table2 = _rows(**{k: {"mflr_b": (m, s), "mflr_c": (m, s), "sc_b": (c, s), "sc_c": (c, s)}
                      for k, (m, c, s) in good.items()})
    table2["M_A"]["rho_b_seeds"] = [0.5, 0.5, 0.5]  # M_A's FLR ranks B's frames by its error
    assert all(f.holds for f in offroad_table2.findings(table2))
    table2["Unif B4"]["mflr_c"] = 41.5  # Ours 40 vs Unif 41.5: within the std of 2
    held = {f.claim: f.holds for f in offroad_table2.findings(table2)}
    assert not held[next(c for c in held if c.startswith("hard frames beat uniform"))]

    names = ["5-class M_A", "5-class D4 (paper D20)", "5-class D8 (paper D40)", "4-class M_A", "4-class D4 (paper D20)",
             "4-class D8 (paper D40)"]
    gain = {"": 0, " known argmax": 2, " + CRF": 5}
    metrics = lambda pa, iou: {"pa": (pa, 0.5), "iou": (iou, 0.5), "pre": (iou, 0.5), "rec": (iou, 0.5),  # noqa: E731
                               "fpr": (100 - pa, 0.5)}
    table3 = _rows(**{f"{n}{r}": metrics(50 + 10 * i + gain[r], 20 + 5 * i + gain[r])
                      for i, n in enumerate(names) for r in gain},
                   **{f"{c}-class supervised D8 (paper D40){r}": metrics(pa + 2 * (r != ""), iou)
                      for c, pa, iou in ((5, 70, 35.3), (4, 100, 50.3)) for r in ("", " + CRF")})
    assert [f.holds for f in offroad_table3.findings(table3)] == [True] * 13
    table3["5-class D8 (paper D40) known argmax"]["pa"] = 104.8  # the CRF only fills unknown: control as good
    assert [f.holds for f in offroad_table3.findings(table3)] == [True, True, True, False] + [True] * 9
    table3["5-class D8 (paper D40) + CRF"]["iou_std"] = 10.0
    assert [f.holds for f in offroad_table3.findings(table3)] == [True, True, False, False] + [True] * 9
    table3["4-class supervised D8 (paper D40) + CRF"]["pa"] = 104.8  # the supervised + CRF as good in PA
    assert [f.holds for f in offroad_table3.findings(table3)][-5:] == [True, True, True, False, True]
    against_supervised = lambda: [offroad_table3.findings(table3)[i].holds for i in (-5, -4, -1)]  # noqa: E731
    # Against the supervised rows: PA and FPR must both be better; "at its level": beaten in no metric.
    table3["4-class supervised D8 (paper D40)"]["fpr"] = -6.0  # supervised FPR -6 < -5 - 0.5: beaten in FPR
    assert against_supervised() == [True, False, False]
    table3["4-class supervised D8 (paper D40)"]["fpr"] = -5.3  # within the spread: neither beats the other
    assert against_supervised() == [True, False, True]
    table3["4-class supervised D8 (paper D40)"]["rec"] = 50.4  # REC 50 vs 50.4: within the spread
    assert [f.holds for f in offroad_table3.findings(table3)][-1]
    table3["4-class supervised D8 (paper D40)"]["rec"] = 51.0
    assert not [f.holds for f in offroad_table3.findings(table3)][-1]


def test_controls_fail_when_their_mechanism_does_not_deliver():
    exp2 = _rows(**{offroad_exp2.CONTROL: {"classes": (6, 0), "clusters": (6.0, 0.0), "recovered": (6.0, 0.0)}})
    row = exp2[offroad_exp2.CONTROL]
    row.update(clusters_seeds=[6, 6, 6], recovered_seeds=[6, 6, 6])
    assert [f.holds for f in offroad_exp2.controls(exp2)] == [True]
    row["clusters_seeds"] = [6, 5, 6]  # one seed off: the control fails (a mean near k is not enough)
    assert [f.holds for f in offroad_exp2.controls(exp2)] == [False]
    row.update(clusters_seeds=[6, 6, 6], recovered_seeds=[6, 6, 5])  # two clusters on one Gaussian
    assert [f.holds for f in offroad_exp2.controls(exp2)] == [False]

    errors = {"Rand B4": [10, 20], "Unif B4": [30, 5], "Ours B4": [40, 30], "Ours B8": [90, 90],
              "control: Oracle B4": [40, 31]}
    table2 = {k: {"error": float(np.mean(e)), "error_std": 0.0, "error_seeds": e} for k, e in errors.items()}
    assert [f.holds for f in offroad_table2.controls(table2)] == [True]  # Ours B8 (another budget) not compared
    table2["control: Oracle B4"]["error_seeds"] = [45, 29]  # below Ours B4 in one seed (not in the mean): fails
    assert [f.holds for f in offroad_table2.controls(table2)] == [False]

    table3 = _rows(**{offroad_table3.CONTROL_NOISY: {"pa": (50, 1), "iou": (30, 1)},
                      offroad_table3.CONTROL_CRF: {"pa": (90, 1), "iou": (70, 1)}})
    assert [f.holds for f in offroad_table3.controls(table3)] == [True]
    table3[offroad_table3.CONTROL_CRF]["iou"] = 30.5
    assert [f.holds for f in offroad_table3.controls(table3)] == [False]


def test_risk_metrics_of_summed_frame_risks_are_mflr_and_scene_coverage():
    from jaxanom.offroad.risk import mean_frame_risk, scene_coverage

    rng = np.random.default_rng(0)
    flr = np.concatenate([rng.uniform(0, 1, 9), [0.5, 0.5]])  # two frames exactly at epsilon: not risky (Eq. 14: >)
    per_frame = np.asarray(offroad_table2.frame_risks(flr, 0.5))
    weights = np.array([rng.integers(0, 3, len(flr)) for _ in range(4)])
    weights[0] = 1
    got = offroad_table2.risk_metrics("c")(weights @ per_frame)
    for r, w in enumerate(weights):
        drawn = np.repeat(flr, w)
        assert got["mflr_c"][r] == pytest.approx(100 * mean_frame_risk(drawn))
        assert got["sc_c"][r] == pytest.approx(100 * scene_coverage(drawn, 0.5))


def _paired_table2(seed_flr: dict, rho=(0.5, 0.5, 0.5)) -> dict:
    """Table II values with paired replicates from per-frame FLRs ``{row: [(F,) per seed]}`` on B and C alike;
    ``rho``: M_A's Spearman rho between FLR and error, per seed."""
    per_seed = [{label: {k: offroad_table2.frame_risks(flrs[s], 0.5) for k in ("b", "c")}
                 for label, flrs in seed_flr.items()} for s in range(len(next(iter(seed_flr.values()))))]
    metrics = {k: (lambda _, k=k: offroad_table2.risk_metrics(k)) for k in ("b", "c")}
    values = {}
    for label, flrs in seed_flr.items():
        means = {f"{m}_{k}": [offroad_table2.risk_metrics(k)(np.sum(offroad_table2.frame_risks(f, 0.5), 0))[f"{m}_{k}"]
                              for f in flrs] for m in ("mflr", "sc") for k in ("b", "c")}
        values[label] = {**{k: float(np.mean(x)) for k, x in means.items()},
                         **{f"{k}_std": float(np.std(x, ddof=1)) for k, x in means.items()}}
    for label, replicates in paired_replicates(per_seed, metrics).items():
        values[label]["replicates"] = replicates
    values["M_A"]["rho_b_seeds"] = list(rho)
    return values


def test_table2_findings_are_paired_and_a_saturated_coverage_is_untested():
    rng = np.random.default_rng(1)
    base = [rng.uniform(0.05, 0.4, 12) * s for s in (0.5, 1.0, 1.5)]  # 3 seeds whose levels differ a lot
    rows = {"M_A": [b + 0.05 for b in base], "Rand B4": [b + 0.02 for b in base], "Unif B4": [b + 0.01 for b in base],
            "Ours B2": [b + 0.004 for b in base], "Ours B4": [b for b in base], "Ours B8": [b - 0.004 for b in base]}
    values = _paired_table2(rows)
    found = {f.claim: f for f in offroad_table2.findings(values)}
    hard = found["hard frames beat uniform frames on C in mFLR (paper 40.67 vs 44.68)"]
    # Ours is 1 point below Unif in every frame: the paired interval excludes 0, though the seeds' std is larger.
    assert hard.holds and hard.tested is None and hard.intervals[0]["high"] < 0
    assert abs(values["Ours B4"]["mflr_c"] - values["Unif B4"]["mflr_c"]) < values["Unif B4"]["mflr_c_std"]
    assert "Δ -1.00 [" in hard.evidence
    coverage = found["hard frames beat uniform frames on C in scene coverage Sc"]  # every FLR <= 0.5: Sc 100 everywhere
    assert not coverage.holds and coverage.tested is False and "saturated" in coverage.untested_because
    assert coverage.untested_because.startswith("Ours B4 and Unif B4 have the same Sc C in every bootstrap replicate")
    assert all(found[c].tested is None for c in found if "Sc" not in c and "coverage" not in c)
    rows["Unif B4"][1] = rows["Unif B4"][1].copy()
    rows["Unif B4"][1][3] = 0.9  # one risky frame: Sc now differs in some replicates, so it is tested
    coverage = {f.claim: f for f in offroad_table2.findings(_paired_table2(rows))}[coverage.claim]
    assert coverage.tested is None and not coverage.holds  # 1 frame of 36: the interval still holds 0
    # M_A's FLR blind to its errors in one seed: the hard-frame claims are untested, the others still tested.
    blind = {f.claim: f for f in offroad_table2.findings(_paired_table2(rows, rho=(0.5, 0.1, 0.6)))}
    assert blind[hard.claim].tested is False and "ρ" not in blind[hard.claim].untested_because
    assert "Spearman rho per seed +0.50, +0.10, +0.60" in blind[hard.claim].untested_because
    seen = {f.claim for f in offroad_table2.findings(_paired_table2(rows)) if f.tested is False}  # saturated Sc
    assert {c for c, f in blind.items() if f.tested is False} == {
        c for c in blind if c.startswith(("hard frames", "mFLR on"))} | seen
    assert blind[hard.claim].holds  # the verdict is kept, only marked untested
    rows["Ours B4"] = [b - 0.02 + 0.01 * np.sin(np.arange(12)) for b in base]  # noisy gain: 1 point, not every frame
    assert {f.claim: f.holds for f in offroad_table2.findings(_paired_table2(rows))}[hard.claim]
    rows["Ours B4"] = [b + 0.01 + 0.1 * np.sin(np.arange(12) + s) for s, b in enumerate(base)]  # no gain: noise only
    assert not {f.claim: f.holds for f in offroad_table2.findings(_paired_table2(rows))}[hard.claim]


def test_rank_correlation_is_spearmans_rho_and_nan_without_a_ranking():
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=20), rng.normal(size=20)
    x[3] = x[4]  # a tie
    ranks = lambda a: np.argsort(np.argsort(a)).astype(float)  # noqa: E731 (no ties in y; x's tie handled below)
    rx = ranks(x)
    rx[[3, 4]] = rx[[3, 4]].mean()  # average ranks of the tie
    assert offroad_table2.rank_correlation(x, y) == pytest.approx(np.corrcoef(rx, ranks(y))[0, 1])
    assert np.isnan(offroad_table2.rank_correlation(np.zeros(5), np.arange(5.0)))
    assert np.isnan(offroad_table2.rank_correlation(np.arange(5.0), np.ones(5)))
