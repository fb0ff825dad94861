"""An attention module on a segmenter other than DeepLabV3+, through the commands: CuDAM on ERFNet
(its tiny preset, tiny frames, a batch per test device) trains a step, and ``fit-stats`` and ``evaluate`` read the run,
scoring with the ``cudam`` method that reads its attention map."""
import json

import pytest

from jaxanom.app.experiment import load_experiment, load_variables
from jaxanom.cli import main


def test_cudam_on_erfnet_trains_and_evaluates_with_the_cudam_method(tmp_path, capsys):
    run, stats = tmp_path / "run", tmp_path / "stats.npz"
    assert main(["train", "--out", str(run), "--model", "erfnet_tiny", "--attention", "cudam", "--steps", "1",
                 "--batch-size", "4", "--set", "crop=16,32", "--set", "height=16", "--set", "width=32",
                 "--set", "train_frames=4", "--no-progress"]) == 0
    # the reward weight at the map ERFNet's encoder gives a 16 x 32 crop: 2 x 4 positions
    assert f"CuDAM tau = {5e4 * 2 * 4 / (180 * 180):.6g} (position deep, gate paper)" in capsys.readouterr().out
    experiment, variables = load_variables(run)
    assert (experiment.model, experiment.attention, experiment.train.objective.name) == ("erfnet_tiny", "cudam", "cudam")
    assert float(variables["params"]["cudam"]["alpha"]) != 0  # the step trained the module
    assert json.loads((run / "experiment.json").read_text())["attention"] == "cudam"  # recorded as before
    assert main(["fit-stats", "--run", str(run), "--frames", "2", "--out", str(stats)]) == 0
    out = tmp_path / "eval"
    assert main(["evaluate", "--run", str(run), "--dataset", "synthetic", "--path", "anomaly", "--frames", "1",
                 "--stats", str(stats), "--methods", "cudam,sml_post", "--out", str(out)]) == 0
    record = json.loads((out / "metrics.json").read_text())
    assert 0 < record["metrics"]["cudam"]["ap"] <= 1
    # evaluate's synthetic frames are 256 x 512; ERFNet's map is at stride 8: 32 x 64
    assert record["cudam_sigma"] == {"values": [2e4 * 32 * 64 / (256 * 512)], "source": "default"}
    assert load_experiment(run) == experiment


def test_a_runs_recorded_cudam_settings_reach_its_network_and_are_recorded_as_before():
    """CuDAM's position and gate stay in the experiment's fields cudam_position / cudam_gate (as every
    earlier experiment.json has them); the network gets them as its attention position and option."""
    from jaxanom.app.experiment import Experiment, build_network, jsonable
    from jaxanom.config_codec import decode

    experiment = Experiment(attention="cudam", cudam_position="output", cudam_gate="scale_free")
    network = build_network(experiment)
    assert (network.attention, network.attention_position, network.attention_options) == \
        ("cudam", "output", (("gate", "scale_free"),))
    values = jsonable(experiment)
    assert (values["attention"], values["cudam_position"], values["cudam_gate"]) == ("cudam", "output", "scale_free")
    assert decode(Experiment, values, "experiment") == experiment
    # MSAAM reads neither field: its network is the same whatever they hold
    msaam = Experiment(attention="msaam", cudam_position="output", cudam_gate="scale_free")
    assert build_network(msaam) == build_network(Experiment(attention="msaam"))


def test_a_cudam_setting_the_network_refuses_is_named_as_the_experiment_records_it():
    """Checked when the experiment is made, before any work: the gate by CuDAM's own check, the
    position by the segmenter's; each named by its experiment field."""
    from jaxanom.app.experiment import Experiment

    with pytest.raises(ValueError, match=r"^cudam_gate: expected one of \('paper', 'scale_free'\), got 'sigmoid'"):
        Experiment(attention="cudam", cudam_gate="sigmoid")
    with pytest.raises(ValueError, match=r"^cudam_position: expected one of \('deep',\) for 'cudam' on this segmenter"):
        Experiment(model="erfnet", attention="cudam", cudam_position="surface")
    with pytest.raises(ValueError, match=r"^attention: expected None or one of \('cudam', 'msaam'"):
        Experiment(attention="cbam")
