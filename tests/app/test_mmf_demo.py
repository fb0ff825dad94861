"""``jaxanom demo mmf --quick``: the whole MMF path (every part trained, cached, scored) in miniature;
``--config`` and ``jaxanom evaluate --mmf`` on the parts it trained."""
import json

import numpy as np
import pytest

from jaxanom.cli import main
from jaxanom.data.image_io import read_rgb
from jaxanom.data.synthetic import SyntheticScenes
from jaxanom.app.evaluate import anomaly_results
from jaxanom.app.demos.mmf import ROWS, MMFDemoConfig
from jaxanom.app.mmf_pipeline import scored_batches
from jaxanom.app.configs import load_config
from jaxanom.app.mmf_pipeline import MMFPipeline

pytestmark = pytest.mark.end_to_end  # every test reads the trained demo


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("mmf_demo")
    assert main(["demo", "mmf", "--quick", "--out", str(out), "--overwrite", "--no-progress"]) == 0
    return out


def test_quick_mmf_demo_writes_the_ablation_and_pictures(demo_dir):
    results = json.loads((demo_dir / "results.json").read_text())
    assert set(results["metrics"]) == {row[0] for row in ROWS}
    for m in results["metrics"].values():
        assert 0 <= m["ap"] <= 1 and 0 <= m["fpr_at_tpr"] <= 1
    assert "| mmf | yes | yes |" in (demo_dir / "table.md").read_text()
    picture = read_rgb(demo_dir / "frame_0.png")
    assert picture.shape[1] >= 4 * 256 and picture.shape[0] >= 2 * 128  # 2 rows of 4 panels, 32 x 64 frames x 4
    parts = sorted(p.name.split("-")[0] for p in (demo_dir / "runs").iterdir())
    assert parts == ["dissimilarity", "dissimilarity", "rgbd", "segmenter", "synthesizer"]
    assert load_config(demo_dir / "results.json", MMFDemoConfig) == MMFDemoConfig.quick()  # a config file


def _tree(folder):
    """Every file under ``folder`` with its size and modification time."""
    return {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.rglob("*")}


def test_a_second_run_from_its_config_file_reuses_every_trained_part(demo_dir, capsys):
    before = {p: sorted(q.name for q in (p / "checkpoints").iterdir())
              for p in (demo_dir / "runs").iterdir() if p.is_dir()}
    config = demo_dir / "config.json"
    config.write_text(json.dumps(json.loads((demo_dir / "results.json").read_text())["config"]))
    assert main(["demo", "mmf", "--config", str(config), "--out", str(demo_dir), "--overwrite", "--no-progress"]) == 0
    after = {p: sorted(q.name for q in (p / "checkpoints").iterdir()) for p in before}
    assert before == after and len(before) == 4
    first = json.loads((demo_dir / "results.json").read_text())["metrics"]
    assert np.isfinite(first["mmf"]["ap"])


def test_evaluate_scores_a_dataset_with_the_trained_pipeline_without_changing_it(demo_dir, tmp_path, capsys):
    runs = _tree(demo_dir / "runs")
    out = tmp_path / "eval"
    assert main(["evaluate", "--mmf", str(demo_dir), "--dataset", "synthetic", "--path", "anomaly", "--frames", "2",
                 "--out", str(out)]) == 0
    record = json.loads((out / "metrics.json").read_text())
    assert set(record["metrics"]) == {row[0] for row in ROWS} and record["frames"] == 2
    assert _tree(demo_dir / "runs") == runs  # read-only
    # the same as scoring those frames with the library
    pipe = MMFPipeline.load(MMFDemoConfig.quick().pipeline, demo_dir / "runs")
    frames = SyntheticScenes("anomaly", 2, seed=1, height=32, width=64, disparity=True, roi=True)
    metrics, _ = anomaly_results(scored_batches(pipe, frames, pipe.config.batch_size), [row[0] for row in ROWS])
    for name, values in metrics.items():
        assert record["metrics"][name]["ap"] == pytest.approx(values["ap"], abs=1e-12)


def test_evaluate_mmf_refuses_what_it_cannot_score(demo_dir, tmp_path, capsys):
    (tmp_path / "not_a_demo").mkdir()
    assert main(["evaluate", "--mmf", str(tmp_path / "not_a_demo"), "--dataset", "synthetic", "--path", "anomaly",
                 "--out", str(tmp_path / "a")]) == 2
    assert "results.json" in capsys.readouterr().err
    assert main(["evaluate", "--mmf", str(demo_dir), "--dataset", "fishyscapes-laf", "--path", str(tmp_path),
                 "--base", str(tmp_path), "--out", str(tmp_path / "b")]) == 2
    assert "disparity" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="2"):  # argparse: --run and --mmf exclude each other
        main(["evaluate", "--mmf", str(demo_dir), "--run", str(demo_dir), "--dataset", "synthetic",
              "--path", "anomaly", "--out", str(tmp_path / "c")])


def test_pipeline_load_names_a_missing_part(demo_dir, tmp_path):
    config = MMFDemoConfig.quick().pipeline
    for part in (demo_dir / "runs").iterdir():
        if part.name.startswith(("segmenter", "rgbd")):
            (tmp_path / part.name).symlink_to(part)
    with pytest.raises(ValueError, match="synthesizer"):
        MMFPipeline.load(config, tmp_path)

