"""``experiments/mmf_table2.py``: seeds, findings on the right rows, and the whole table path with
untrained parts (the training itself is covered by ``test_mmf_demo``)."""
import dataclasses
import json
import types

import jax
import numpy as np
import pytest

from experiments import mmf_table2 as exp
from experiments.__main__ import EXPERIMENTS, write_results
from experiments.common import Scale
from jaxanom.app.experiment import build_network
from jaxanom.app import mmf_pipeline as pipeline
from jaxanom.train.step import model_input


def test_seeds_sizes_and_smoke_detection():
    assert exp.is_smoke(Scale.smoke()) and exp.is_smoke(dataclasses.replace(Scale.smoke(), seed=5))
    assert not exp.is_smoke(Scale()) and not exp.is_smoke(dataclasses.replace(Scale.smoke(), steps=3))
    quick = exp.demo_config(dataclasses.replace(Scale.smoke(), seed=2))
    assert quick.pipeline.segmenter.train.seed == 6 and quick.anomaly_frames == Scale.smoke().anomaly_frames
    quick_config = pipeline.MMFConfig.quick()
    assert dataclasses.replace(quick.pipeline, segmenter=quick_config.segmenter) == quick_config
    full = exp.demo_config(Scale(seed=1))
    assert full.pipeline.segmenter.train.seed == 3 and full.anomaly_frames == exp.ANOMALY_FRAMES
    assert full.pipeline.dissim_steps == exp.PRESET.dissim_steps and full.pipeline.segmenter.height == 64
    # every part of another seed is another folder
    assert all(full.pipeline.part_key(p) != exp.demo_config(Scale(seed=2)).pipeline.part_key(p)
               for p in ("segmenter", "rgbd", "synthesizer", "dissimilarity"))
    with pytest.raises(ValueError, match="synthetic"):
        exp.demo_config(Scale(cityscapes_root="/data/cityscapes"))
    assert EXPERIMENTS[-1] == exp.NAME


def _values(ap: dict, fpr95: dict, std: float = 0.0) -> dict:
    return {label: {"ap": ap[label], "fpr95": fpr95[label], "ap_std": std, "fpr95_std": std} for label in ap}


def test_findings_read_the_rows_they_name():
    labels = [row[0] for row in exp.ROWS]
    ap = dict.fromkeys(labels, 10.0)
    fpr = dict.fromkeys(labels, 90.0)
    # only the assistant maps raise AP; only the post-processor lowers FPR95; MMF best in both
    ap.update({exp.ASSISTED: 30.0, exp.FULL: 40.0, "entropy": 20.0})
    fpr.update({exp.POST: 50.0, exp.FULL: 40.0, "entropy": 60.0})
    got = {f.claim: f.holds for f in exp.findings(_values(ap, fpr))}
    assert all(got.values()), got
    # the same with a spread larger than every difference: no comparison in favour holds
    spread = {f.claim: f.holds for f in exp.findings(_values(ap, fpr, std=100.0))}
    assert [c for c, h in spread.items() if h] == ["the assistant maps do not clearly lower FPR95"]
    # swap the roles of the two mechanisms: the mechanism-specific claims fail
    ap.update({exp.ASSISTED: 10.0, exp.POST: 30.0})
    fpr.update({exp.POST: 90.0, exp.ASSISTED: 50.0})
    swapped = {f.claim: f.holds for f in exp.findings(_values(ap, fpr))}
    assert not swapped["the assistant maps raise the resynthesis net's AP"]
    assert not swapped["the assistant maps do not clearly lower FPR95"]
    assert not swapped["the post-processor lowers the resynthesis net's FPR95"]


@pytest.fixture
def untrained_parts(monkeypatch):
    """The pipeline's parts at their initial weights: every training call replaced by ``init``."""

    def run_training(experiment, run_dir, **_):
        image = np.zeros((1, experiment.height, experiment.width, 3), np.float32)
        return build_network(experiment).init(jax.random.key(experiment.train.seed), image, train=False)

    def train(config, model, stream):
        batch = next(iter(stream))
        extras = {k: np.asarray(batch[k][:1]) for k in model.extra_inputs}
        variables = model.init(jax.random.key(config.seed), model_input(np.asarray(batch["image"][:1])), train=False,
                               **extras)
        return types.SimpleNamespace(variables=variables)

    monkeypatch.setattr(pipeline, "run_training", run_training)
    monkeypatch.setattr(pipeline, "train", train)


def test_table_over_two_seeds_is_written_and_summarised(tmp_path, untrained_parts):
    out, runs = tmp_path / "out", tmp_path / "runs"
    result = exp.run(Scale.smoke(), 2, out, runs, log=lambda *_: None, description="MMF smoke.")
    assert sorted(p.name for p in out.iterdir()) == [f"{exp.NAME}{s}" for s in (".json", ".md", "_pr.png", "_roc.png")]
    saved = json.loads((out / f"{exp.NAME}.json").read_text())
    assert saved["num_seeds"] == 2 and saved["scale"]["height"] == 32 and saved["scale"]["width"] == 64
    rows = {row["label"]: row for row in saved["table"]}
    assert list(rows) == [row[0] for row in exp.ROWS] + [label for label, _ in exp.SLIC_VARIANTS]
    for label, method in [row[:2] for row in exp.ROWS] + [(label, "mmf") for label, _ in exp.SLIC_VARIANTS]:
        row = rows[label]
        assert row["score"] == method and len(row["ap_seeds"]) == 2
        for metric in ("ap", "fpr95", "auroc", "miou"):
            assert all(0 <= x <= 100 for x in row[f"{metric}_seeds"])
            assert np.isclose(row[metric], np.mean(row[f"{metric}_seeds"]))
            assert np.isclose(row[f"{metric}_std"], np.std(row[f"{metric}_seeds"], ddof=1))
        # the two seeds are two pipelines: other networks, named by the part that scores the row
        first, second = row["networks"]
        part = "segmenter" if method in {"entropy", "msp", "max_logit", "sml"} else "dissimilarity"
        assert first != second and first.split("-")[0] == part
    assert rows["resynthesis"]["network"] == rows["resynthesis + post-processor"]["network"]
    assert rows["resynthesis"]["network"] != rows["resynthesis + assistant maps"]["network"]
    assert set(saved["networks"]) == {n for row in saved["table"] for n in row["networks"]}
    assert saved["findings"] == [dataclasses.asdict(f) for f in exp.findings(result_values(saved))]
    assert saved["description"].startswith("MMF smoke. Sizes: 32 x 64")
    table_text = (out / f"{exp.NAME}.md").read_text()  # each network's own step count, not one for all
    assert "training steps per network" not in table_text and "training steps: segmenter" in table_text
    assert "SLIC step 1 px on the image" in saved["description"]  # scaled_step((32, 64)) = 1
    text = write_results(out).read_text()
    assert exp.TITLE in text and "| MMF (assistant maps + post-processor) | `mmf` |" in text


def result_values(saved: dict) -> dict:
    return {row["label"]: row for row in saved["table"]}
