"""docs/extending.md runs as written (``tests/doc_examples.py``): its package ``myext`` is written
into an empty folder, its method scores a tiny logits file through ``jaxanom score --plugin`` (an
option set by ``--set methods.NAME.OPTION=``), its objective trains a tiny network two steps through
``train --plugin``, its evaluator runs through ``run_evaluators``, ``score --evaluators`` and
``evaluate --evaluators``, its protocol through ``evaluate --protocol``, its attention module
attaches to two segmenters and trains a step through ``train --plugin``. In a process of its own,
so what the page registers stays there."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from doc_examples import run_page

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "extending.md"


def test_the_extension_authors_page_runs_as_written(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, str(ROOT / "tests" / "doc_examples.py"), str(PAGE), str(tmp_path)],
                            capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    metrics = json.loads((tmp_path / "scored" / "metrics.json").read_text())["metrics"]
    assert {"temperature_msp", "temperature_msp+post"} <= set(metrics)
    assert json.loads((tmp_path / "focal_run" / "experiment.json").read_text())["train"]["objective"]["name"] == "focal"
    assert "$ jaxanom train --plugin myext.objectives" in result.stdout  # the commands ran, in page order
    assert json.loads((tmp_path / "scored_hot" / "metrics.json").read_text())["metrics"]["temperature_msp"][
        "options"] == {"temperature": 2.0}
    gaps = json.loads((tmp_path / "gaps" / "metrics.json").read_text())["metrics"]["temperature_msp"]["evaluators"]
    assert set(gaps) == {"score_gap", "pixel"}
    small = json.loads((tmp_path / "small_eval" / "metrics.json").read_text())
    assert small["protocol"] == "small"
    assert {name: set(m.get("evaluators", ())) for name, m in small["metrics"].items()} == {
        "msp": {"score_gap"}, "temperature_msp": {"score_gap"}}
    # the attention module, on ERFNet's encoder output (16 channels in erfnet_tiny) and DeepLabV3+'s (64)
    assert "erfnet_tiny (1, 32, 64, 19) (1, 16) ['expand', 'reduce']" in result.stdout
    assert "deeplabv3plus_tiny (1, 32, 64, 19) (1, 64) ['expand', 'reduce']" in result.stdout
    assert json.loads((tmp_path / "gated_run" / "experiment.json").read_text())["plugins"] == ["myext.attention"]


def test_a_page_runs_its_files_blocks_and_commands_and_refuses_a_line_it_would_not_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # run_page moves into its folder and puts it on sys.path: both restored after
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "work").mkdir()
    page = tmp_path / "page.md"
    page.write_text("```python\n# file: doc_examples_probe/__init__.py\nVALUE = 3\n```\n"
                    "```python\nimport pathlib\nfrom doc_examples_probe import VALUE\n"
                    "pathlib.Path('seen').write_text(str(VALUE))\n```\n"
                    "```bash\nexport PYTHONPATH=$PWD\nls -l  # not a jaxanom command\n```\n")
    with pytest.raises(AssertionError, match=r"page.md block 2: not a jaxanom command: \['ls', '-l'\]"):
        run_page(page, tmp_path / "work")
    assert (tmp_path / "work" / "seen").read_text() == "3"

    page.write_text("```bash\njaxanom score --logits missing.npy --out o\n```\n")
    with pytest.raises(AssertionError, match="block 0: jaxanom score --logits missing.npy --out o failed"):
        run_page(page, tmp_path / "work")
