"""The ``jaxanom`` command end to end on tiny settings, and its one-line errors."""
import json

import numpy as np
import pytest
from sklearn.metrics import average_precision_score, roc_auc_score

from jaxanom.cli import main
from jaxanom.data.image_io import read_rgb



@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--quick", "--out", str(out), "--overwrite", "--no-progress"]) == 0
    return out


def test_quick_demo_writes_its_results(demo_dir):
    results = json.loads((demo_dir / "results.json").read_text())
    metrics = results["anomaly"]["metrics"]
    assert set(metrics) == {"msp", "max_logit", "entropy", "energy", "sml", "sml_post", "cudam"}
    for values in metrics.values():
        assert 0.0 <= values["ap"] <= 1.0 and 0.0 <= values["auroc"] <= 1.0
    assert 0.0 <= results["segmentation"]["miou"] <= 1.0
    for name in ("roc.png", "pr.png", "frame_0.png", "sml_stats.npz", "run/experiment.json"):
        assert (demo_dir / name).is_file(), name
    picture = read_rgb(demo_dir / "frame_0.png")  # 2 rows of 3 panels, 64 x 96 frames x 3
    assert picture.shape[1] >= 3 * 288 and picture.shape[0] >= 2 * 192, picture.shape
    assert list((demo_dir / "run" / "checkpoints").iterdir())
    # the outputs hold the configuration as config files: the demo's and its run's
    from jaxanom.app.configs import load_config
    from jaxanom.app.demos.sml_cudam import DemoConfig
    from jaxanom.app.experiment import Experiment, load_experiment

    assert load_config(demo_dir / "results.json", DemoConfig) == DemoConfig.quick()
    assert load_experiment(demo_dir / "run") == load_config(demo_dir / "run" / "experiment.json", Experiment) == \
        DemoConfig.quick().experiment


def test_demo_refuses_a_non_empty_folder(demo_dir, capsys):
    assert main(["demo", "--quick", "--out", str(demo_dir)]) == 2
    error = capsys.readouterr().err.strip()
    assert "not empty" in error and len(error.splitlines()) == 1


def test_fit_stats_and_evaluate_from_the_demo_run(demo_dir, tmp_path, capsys):
    stats = tmp_path / "stats.npz"
    assert main(["fit-stats", "--run", str(demo_dir / "run"), "--frames", "4", "--missing", "pooled",
                 "--out", str(stats)]) == 0
    with np.load(stats) as data:
        assert data["mean"].shape == (19,) and (data["std"] > 0).all()
    out = tmp_path / "eval"
    assert main(["evaluate", "--run", str(demo_dir / "run"), "--dataset", "synthetic", "--path", "anomaly",
                 "--frames", "2", "--stats", str(stats), "--methods", "msp,sml_post,cudam",
                 "--out", str(out), "--pictures", "1"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    assert set(metrics) == {"msp", "sml_post", "cudam"}
    assert read_rgb(out / "frame_0.png").shape[1] >= 3 * 288
    assert "| sml_post |" in capsys.readouterr().out


def test_evaluate_reads_real_road_anomaly_frames(demo_dir, tmp_path, road_anomaly_sample):
    out = tmp_path / "real"
    assert main(["evaluate", "--run", str(demo_dir / "run"), "--dataset", "road-anomaly",
                 "--path", str(road_anomaly_sample),
                 "--methods", "msp,max_logit", "--out", str(out)]) == 0
    result = json.loads((out / "metrics.json").read_text())
    assert result["frames"] == 6
    assert result["metrics"]["msp"]["num_positives"] > 0


def test_evaluate_missing_dataset_folder_is_one_line(demo_dir, tmp_path, capsys):
    code = main(["evaluate", "--run", str(demo_dir / "run"), "--dataset", "road-anomaly", "--methods", "msp",
                 "--path", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "nowhere" in error and len(error.splitlines()) == 1


def _softmax_max(logits_nchw):
    shifted = logits_nchw - logits_nchw.max(axis=1, keepdims=True)
    probabilities = np.exp(shifted) / np.exp(shifted).sum(axis=1, keepdims=True)
    return probabilities.max(axis=1)


def test_score_logits_saved_by_numpy_match_scikit_learn(tmp_path):
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(3, 5, 9, 11)).astype(np.float32)  # NCHW, as PyTorch saves them
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(3, 9, 11), p=[0.6, 0.3, 0.1])
    np.save(tmp_path / "logits.npy", logits)
    np.savez(tmp_path / "labels.npz", labels=labels)
    out = tmp_path / "out"
    assert main(["score", "--logits", str(tmp_path / "logits.npy"), "--labels", str(tmp_path / "labels.npz"),
                 "--methods", "msp,max_logit", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    valid = labels != 255
    msp = -_softmax_max(logits.astype(np.float64))
    assert metrics["msp"]["ap"] == pytest.approx(average_precision_score(labels[valid], msp[valid]), rel=1e-5)
    assert metrics["msp"]["auroc"] == pytest.approx(roc_auc_score(labels[valid], msp[valid]), rel=1e-5)
    max_logit = -logits.max(axis=1)
    assert metrics["max_logit"]["auroc"] == pytest.approx(roc_auc_score(labels[valid], max_logit[valid]), rel=1e-6)
    np.testing.assert_allclose(np.load(out / "scores" / "max_logit.npy"), max_logit, rtol=1e-6)


def test_score_reports_the_envelope_ap(tmp_path):
    from jaxanom.metrics import anomaly_metrics

    rng = np.random.default_rng(1)
    logits = rng.normal(size=(2, 4, 6, 7)).astype(np.float32)
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(2, 6, 7), p=[0.6, 0.3, 0.1])
    np.save(tmp_path / "logits.npy", logits)
    np.save(tmp_path / "labels.npy", labels)
    assert main(["score", "--logits", str(tmp_path / "logits.npy"), "--labels", str(tmp_path / "labels.npy"),
                 "--methods", "max_logit", "--ap-convention", "envelope", "--out", str(tmp_path / "out")]) == 0
    got = json.loads((tmp_path / "out" / "metrics.json").read_text())["metrics"]["max_logit"]
    assert got["ap_convention"] == "envelope"
    assert got["ap"] == pytest.approx(anomaly_metrics(-logits.max(axis=1), labels, ap_convention="envelope")["ap"])


@pytest.mark.parametrize("problem, message", [
    ("nan", "finite"), ("stats", "classes"), ("labels", "labels"), ("rank", "4 dimensions"),
    ("label-values", "image 1: labels: expected values in {0, 1, 255}")])
def test_score_bad_input_is_one_line(tmp_path, capsys, problem, message):
    logits = np.zeros((2, 3, 4, 5), np.float32)
    labels = np.zeros((2, 4, 5), np.uint8)
    labels[:, 0, 0] = 1  # both classes: the metrics are defined
    args = ["--methods", "msp"]
    if problem == "nan":
        logits[0, 0, 0, 0] = np.nan
    if problem == "stats":
        np.savez(tmp_path / "s.npz", mean=np.zeros(7, np.float32), std=np.ones(7, np.float32),
                 counts=np.ones(7, np.int64))
        args = ["--stats", str(tmp_path / "s.npz"), "--methods", "sml"]
    if problem == "labels":
        labels = labels[:, :3]
    if problem == "label-values":  # refused by the metrics' evaluator, named by the image
        labels[1, 2, 2] = 7
    if problem == "rank":
        logits = logits[0]
    np.save(tmp_path / "l.npy", logits)
    np.save(tmp_path / "y.npy", labels)
    code = main(["score", "--logits", str(tmp_path / "l.npy"), "--labels", str(tmp_path / "y.npy"),
                 "--out", str(tmp_path / "o"), *args])
    error = capsys.readouterr().err.strip()
    assert code == 2 and message in error and len(error.splitlines()) == 1, error


def test_train_resume_continues_its_own_run(tmp_path, capsys):
    config = tmp_path / "exp.py"
    config.write_text("from jaxanom.app.demos.sml_cudam import DemoConfig\nexperiment = DemoConfig.quick().experiment\n")
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--out", str(run), "--no-progress"]) == 0
    assert main(["train", "--config", str(config), "--out", str(run), "--no-progress"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert main(["train", "--resume", "--out", str(run), "--steps", "4", "--no-progress"]) == 2
    assert "--steps: the run in" in capsys.readouterr().err  # its poly schedule ends at step 3
    assert main(["train", "--resume", "--out", str(run), "--no-progress"]) == 0
    lines = (run / "log.jsonl").read_text().splitlines()
    assert [json.loads(line)["step"] for line in lines if "train/loss" in line] == [1, 2, 3]


def test_fit_stats_policy_table_warning_and_evaluate_records_it(demo_dir, tmp_path, capsys):
    stats = tmp_path / "stats.npz"
    assert main(["fit-stats", "--run", str(demo_dir / "run"), "--frames", "4", "--policy", "min_count",
                 "--min-count", "500", "--out", str(stats)]) == 0
    captured = capsys.readouterr()
    with np.load(stats) as data:
        counts, status = data["counts"], data["status"].tolist()
    pooled = [c for c in range(19) if counts[c] < 500]
    assert pooled and status == ["pooled" if c in pooled else "fitted" for c in range(19)]
    assert len(captured.out.splitlines()) >= 20 and "pooled" in captured.out
    assert "warning" in captured.err and str(pooled) in captured.err
    out = tmp_path / "eval"
    assert main(["evaluate", "--run", str(demo_dir / "run"), "--dataset", "synthetic", "--path", "anomaly",
                 "--frames", "2", "--stats", str(stats), "--methods", "sml,cudam", "--out", str(out)]) == 0
    record = json.loads((out / "metrics.json").read_text())
    assert record["sml_statistics"]["classes"] == {"pooled": pooled, "shrunk": []}
    assert record["sml_statistics"]["policy"]["policy"] == "min_count"
    # evaluate's synthetic frames are 256 x 512; the demo network's CuDAM map is at stride 4: 64 x 128
    assert record["cudam_sigma"] == {"values": [pytest.approx(2e4 * 64 * 128 / (256 * 512))],
                                     "source": "default"}
    out2 = tmp_path / "eval2"
    assert main(["evaluate", "--run", str(demo_dir / "run"), "--dataset", "synthetic", "--path", "anomaly",
                 "--frames", "2", "--stats", str(stats), "--methods", "cudam", "--cudam-sigma", "3",
                 "--out", str(out2)]) == 0
    assert json.loads((out2 / "metrics.json").read_text())["cudam_sigma"] == {"values": [3.0], "source": "given"}


def test_train_uses_the_paper_equivalent_tau_for_its_map(tmp_path, capsys, monkeypatch):
    """What ``train`` hands the trainer and prints; the training itself is the other tests' (its step
    would only repeat theirs at another map size)."""
    import jaxanom.app.experiment as experiment_module

    trained = []
    monkeypatch.setattr(experiment_module, "run_training", lambda experiment, *_, **__: trained.append(experiment))
    config = tmp_path / "exp.py"
    config.write_text("import dataclasses\nfrom jaxanom.app.demos.sml_cudam import DemoConfig\n"
                      "from jaxanom.cudam.objective import CuDAM\n"
                      "e = DemoConfig.quick().experiment\n"
                      "experiment = dataclasses.replace(e, train=dataclasses.replace(e.train, objective=CuDAM()))\n")
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "run"), "--cudam-position", "output",
                 "--no-progress"]) == 0
    [experiment] = trained
    assert experiment.cudam_position == "output" and experiment.train.objective.tau is None
    # "output": the network's map covers the 64 x 96 crop itself; the paper's tau 5e4 is for 180 x 180 maps
    tau = 5e4 * 64 * 96 / (180 * 180)
    assert f"CuDAM tau = {tau:.6g} (position output" in capsys.readouterr().out


def test_fit_stats_refuses_non_finite_statistics_and_names_its_flags(demo_dir, tmp_path, capsys):
    """--strength 1e308 once wrote std = inf with exit 0; the advice named library arguments."""
    stats = tmp_path / "s.npz"
    code = main(["fit-stats", "--run", str(demo_dir / "run"), "--frames", "4", "--policy", "shrink",
                 "--strength", "1e308", "--out", str(stats)])
    error = capsys.readouterr().err.strip()
    assert code == 2 and len(error.splitlines()) == 1 and "smaller --strength" in error, error
    assert not stats.exists() and not list(tmp_path.iterdir())
    code = main(["fit-stats", "--run", str(demo_dir / "run"), "--frames", "1", "--policy", "none", "--out", str(stats)])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "pass --missing pooled, or --policy min_count or shrink" in error, error
    assert 'missing="pooled"' not in error and not stats.exists()
