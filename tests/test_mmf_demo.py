"""``jaxanom demo mmf --quick``: the whole MMF path (every part trained, cached, scored) in miniature."""
import json

import numpy as np
import pytest

from jaxanom.cli import main
from jaxanom.data.image_io import read_rgb
from jaxanom.mmf.demo import ROWS


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
    assert picture.shape[1] == 6 * picture.shape[0] * 2  # six 32 x 64 panels side by side
    parts = sorted(p.name.split("-")[0] for p in (demo_dir / "runs").iterdir())
    assert parts == ["dissimilarity", "dissimilarity", "rgbd", "segmenter", "synthesizer"]


def test_a_second_run_reuses_every_trained_part(demo_dir, capsys):
    before = {p: sorted(q.name for q in (p / "checkpoints").iterdir())
              for p in (demo_dir / "runs").iterdir() if p.is_dir()}
    assert main(["demo", "mmf", "--quick", "--out", str(demo_dir), "--overwrite", "--no-progress"]) == 0
    after = {p: sorted(q.name for q in (p / "checkpoints").iterdir()) for p in before}
    assert before == after and len(before) == 4
    first = json.loads((demo_dir / "results.json").read_text())["metrics"]
    assert np.isfinite(first["mmf"]["ap"])
