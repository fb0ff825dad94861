"""The off-road experiments: a seconds-long smoke run of all three, and their findings on hand-made values."""
import json
import math

from experiments import offroad_exp2, offroad_table2, offroad_table3
from experiments.__main__ import summary
from experiments.common import Scale
from experiments.offroad_common import OffroadSizes, offroad_sizes, per_seed


def test_smoke_run_writes_tables_that_the_summary_includes(tmp_path):
    out, runs, quiet = tmp_path / "out", tmp_path / "runs", (lambda *_: None)
    results = [module.run(Scale.smoke(), 1, out, runs, log=quiet, description=f"{module.NAME} text.")
               for module in (offroad_exp2, offroad_table2, offroad_table3)]
    assert sorted(p.name for p in out.iterdir()) == sorted(f"{r['name']}.{ext}" for r in results for ext in ("json", "md"))
    for result in results:
        saved = json.loads((out / f"{result['name']}.json").read_text())
        assert saved == json.loads(json.dumps(result)) and saved["num_seeds"] == 1
        assert saved["findings"] and all(f["evidence"] and f["intervals"] == [] and f["tested"] is None
                                         for f in saved["findings"])  # no paired intervals, no mIoU bar: none invented
        assert (out / f"{result['name']}.md").read_text() == saved["report"] + "\n"
        assert saved["report"].startswith(f"## {saved['title']}\n\n{saved['name']} text.\n")
    exp2, table2, table3 = ({row["label"]: row for row in r["table"]} for r in results)
    assert list(exp2) == ["LV1", "LV2", "LV3"] and [exp2[k]["classes"] for k in exp2] == [4, 6, 10]
    assert all(row["clusters"] in (2, 3) and 1 <= row["recovered"] <= row["clusters"] for row in exp2.values())
    sizes = offroad_sizes(Scale.smoke())
    assert list(table2) == ["M_A", "Rand B2", "Unif B2", "Ours B1", "Ours B2", "Ours B2 + triggered round"]
    for label, row in table2.items():
        assert all(0 <= row[k] <= 100 for k in ("mflr_b", "mflr_c", "sc_b", "sc_c", "pa_b", "pa_c", "miou_b", "miou_c"))
        if "+" in label:  # the second round's frames join the first's (it ran only if the trigger fired)
            assert row["rounds"] in (1, 2) and 2 <= len(row["frames"]) <= 2 * row["rounds"]
            continue
        assert len(row["frames"]) == (0 if label == "M_A" else int(label[-1]))
        assert all(b - a > sizes.gap for a, b in zip(row["frames"], row["frames"][1:])) or label.startswith("Unif")
    assert list(table3)[:3] == ["5-class M_A", "5-class M_A known argmax", "5-class M_A + CRF"] and len(table3) == 18
    for label, row in table3.items():
        assert 0 <= row["pa"] <= 100 and 0 <= row["iou"] <= 100 and math.isfinite(row["iou"])
        assert all(0 <= row[k] <= 100 or math.isnan(row[k]) for k in ("pre", "rec", "fpr"))
        assert row["clusters"] == 5 if label.startswith("5-class") else row["clusters"] in (2, 3)
    # The summary renders each experiment's own table (no ROC/PR curve lines for them).
    text = summary([json.loads((out / f"{r['name']}.json").read_text()) for r in results])
    assert all(r["report"] in text for r in results) and "offroad_exp2_roc.png" not in text
    per_paper = text[text.index("### off-road"):text.index("## Tables")]  # said to lack intervals, not given any
    assert "no paired interval" in per_paper and "no segmenter mIoU" in per_paper and "Δ" not in per_paper
    # A rerun reads every seed's values from the cache: same tables, nothing recomputed.
    again = offroad_table2.run(Scale.smoke(), 1, tmp_path / "again", runs, log=quiet)
    assert again["table"] == results[1]["table"]


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
    assert all(f.holds for f in offroad_table2.findings(table2))
    table2["Unif B4"]["mflr_c"] = 41.5  # Ours 40 vs Unif 41.5: within the std of 2
    held = {f.claim: f.holds for f in offroad_table2.findings(table2)}
    assert not held[next(c for c in held if c.startswith("hard frames beat uniform"))]

    names = ["5-class M_A", "5-class D4 (paper D20)", "5-class D8 (paper D40)", "4-class M_A", "4-class D4 (paper D20)",
             "4-class D8 (paper D40)"]
    gain = {"": 0, " known argmax": 2, " + CRF": 5}
    table3 = _rows(**{f"{n}{r}": {"pa": (50 + 10 * i + gain[r], 0.5), "iou": (20 + 5 * i + gain[r], 0.5)}
                      for i, n in enumerate(names) for r in gain})
    assert [f.holds for f in offroad_table3.findings(table3)] == [True] * 8
    table3["5-class D8 (paper D40) known argmax"]["pa"] = 104.8  # the CRF only fills unknown: control as good
    assert [f.holds for f in offroad_table3.findings(table3)] == [True, True, True, False, True, True, True, True]
    table3["5-class D8 (paper D40) + CRF"]["iou_std"] = 10.0
    assert [f.holds for f in offroad_table3.findings(table3)] == [True, True, False, False, True, True, True, True]
