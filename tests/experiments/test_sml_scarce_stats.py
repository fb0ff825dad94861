"""``experiments/sml_scarce_stats.py``: its rows, findings and positive control on a network of random
weights (no training: ``trained`` is replaced by ``tiny_models.random_variables``)."""
import functools
import json

import numpy as np
import pytest

from experiments import sml_scarce_stats as exp
from experiments.common import LOGIT_SCALE_CONTROL, Scale
from tiny_models import random_variables


@pytest.fixture
def untrained(monkeypatch):
    def trained(net, runs, log=print):
        e = net.experiment
        image = np.zeros((1, e.height, e.width, 3), np.float32)
        return random_variables(e.train.seed, functools.partial(net.module().init, train=False), image)

    monkeypatch.setattr(exp, "trained", trained)
    monkeypatch.setattr(exp, "STATS_FRAMES", (2, 8))
    monkeypatch.setattr(exp, "CONTROL_FRAMES", 8)


def test_the_control_refits_sml_on_the_scaled_logits_and_is_reported_apart(tmp_path, untrained):
    result = exp.run(Scale.smoke(), 1, tmp_path, tmp_path / "runs", log=lambda *_: None)
    saved = json.loads((tmp_path / f"{exp.NAME}.json").read_text())
    rows = {row["label"]: row for row in saved["table"]}
    scaled_sml, scaled_max = LOGIT_SCALE_CONTROL + "SML", LOGIT_SCALE_CONTROL + "max logit"
    assert list(rows)[-2:] == [scaled_max, scaled_sml]
    # SML with statistics fitted on the scaled logits is SML of the original ones: the scales divide out
    # (with the same 8 frames and policy) up to float rounding, which reorders the many tied pixels of
    # flat synthetic regions (0.02 points of AP here; statistics of the unscaled logits: 0.5); max logit
    # is not, the scales rank its pixels
    for metric in ("ap", "fpr95", "auroc"):
        assert rows[scaled_sml][metric] == pytest.approx(rows["sml, none, 8 frames"][metric], abs=0.1)
    assert abs(rows[scaled_max]["ap"] - rows["max_logit"]["ap"]) > 1e-3
    assert [c["claim"] for c in saved["controls"]] == ["SML beats max logit when the classes' logit scales differ "
                                                        "(1/4 to 4)"]
    assert saved["controls"][0]["rows"] == [scaled_sml, scaled_max] and saved["paired"]
    # the control is not one of the findings: 2 statistics sizes x (3 policies vs max logit + 2 vs none)
    assert len(saved["findings"]) == 10 and not any("control" in f["claim"] for f in saved["findings"])
    assert result["controls"] == saved["controls"]
