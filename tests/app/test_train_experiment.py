"""Training an Experiment: the network and the objective agree, the default included; a run folder
keeps its experiment (the field that differs is named, steps may grow); experiment.json files of
earlier versions still load."""
import copy
import dataclasses
import json

import numpy as np
import pytest

from jaxanom.app.experiment import (Experiment, check_objective, check_same_run, load_experiment,
                                    run_training)
from jaxanom.cli import main
from jaxanom.config_codec import decode
from jaxanom.cudam.objective import CuDAM
from jaxanom.losses import CrossEntropy
from jaxanom.msaam.objective import MSAAM
from jaxanom.train.checkpoint import Checkpointer
from jaxanom.train.segmenter import TrainConfig
from jaxanom.train.optim import OptimConfig

# experiment.json of Experiment() as the version with one LossConfig wrote it (attention "cudam"
# with the plain loss was that version's default)
LEGACY = json.loads("""{"model": "deeplabv3plus_tiny", "attention": "cudam", "cudam_position": "deep",
"cudam_gate": "paper", "output_stride": 16, "num_classes": 19, "data": "synthetic", "data_root": null,
"train_frames": 256, "height": 128, "width": 256, "crop": [128, 256], "scale_range": [0.75, 1.5], "batch_size": 8,
"train": {"run_dir": "", "steps": 40000, "seed": 0, "loss": {"method": "plain", "ignore": 255, "class_weights": null,
"tau": 50000.0, "reward_prob": 0.5, "beta": 0.5, "attention_literal": false, "msaam_lambda": 0.1,
"msaam_literal": false, "compute_dtype": "float32", "attention_k": "msp", "sml_decay": 0.99},
"optim": {"name": "sgd", "lr": 0.01, "momentum": 0.9, "weight_decay": 0.0005, "poly_power": 0.9, "warmup_steps": 0,
"end_lr": 0.0, "clip_norm": null, "accum_steps": 1}, "eval_every": 2000, "save_every": 1000, "keep": 3,
"progress": true, "distributed": false}, "init_from": null, "init_modules": null}""")


def with_objective(experiment: Experiment, objective) -> Experiment:
    return dataclasses.replace(experiment, train=dataclasses.replace(experiment.train, objective=objective))


def test_the_default_experiment_is_a_plain_network_with_cross_entropy_and_every_paper_pair_agrees():
    assert Experiment().attention is None and Experiment().train.objective == CrossEntropy()
    check_objective(Experiment())
    for attention, objective in ((None, CrossEntropy((1.0,) * 19)), ("cudam", CuDAM()), ("msaam", MSAAM()),
                                 ("cudam", CuDAM(reward_prob=0.0, beta=0.0))):
        check_objective(with_objective(Experiment(attention=attention), objective))


@pytest.mark.parametrize("attention, objective, fragments", [
    ("cudam", CrossEntropy(), ["attention=None with it, or train.objective=CuDAM(...)"]),
    (None, CuDAM(), ["attention=None", "objective 'cudam' reads 'attention'", "attention='cudam' with it"]),
    ("msaam", CuDAM(), ["attention='msaam'", "reading 'branch_weights'", "train.objective=MSAAM(...)"]),
    ("cudam", MSAAM(), ["objective 'msaam' reads 'branch_weights'", "attention='msaam' with it"]),
])
def test_a_network_and_objective_that_disagree_are_refused_in_one_line_naming_both(tmp_path, monkeypatch, attention,
                                                                                objective, fragments):
    import jaxanom.train.segmenter

    monkeypatch.setattr(jaxanom.train.segmenter, "train", lambda *_, **__: pytest.fail("training started"))
    experiment = with_objective(Experiment(attention=attention), objective)
    with pytest.raises(ValueError) as error:
        run_training(experiment, tmp_path / "run")
    message = str(error.value)
    assert message.startswith("attention and train.objective disagree: ") and "\n" not in message
    assert all(fragment in message for fragment in fragments), message
    assert not (tmp_path / "run").exists()  # refused before any work


def test_train_without_flags_hands_training_an_agreeing_default(tmp_path, monkeypatch, capsys):
    import jaxanom.app.experiment as app

    handed = []
    monkeypatch.setattr(app, "run_training", lambda experiment, out, **_: handed.append(experiment))
    assert main(["train", "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    assert handed == [Experiment()]
    assert "CuDAM tau" not in capsys.readouterr().out  # no CuDAM tau that no loss uses

    assert main(["train", "--out", str(tmp_path / "cudam"), "--attention", "cudam", "--no-progress"]) == 0
    assert handed[-1].attention == "cudam" and handed[-1].train.objective == CuDAM()
    # the default crop 128 x 256, CuDAM's map at stride 4: 32 x 64 positions; the paper's 5e4 is for 180 x 180
    assert f"CuDAM tau = {5e4 * 32 * 64 / (180 * 180):.6g} " in capsys.readouterr().out


def test_a_config_file_that_disagrees_is_one_line_and_attention_flag_brings_its_objective(tmp_path, monkeypatch,
                                                                                           capsys):
    import jaxanom.app.experiment as app

    handed = []
    monkeypatch.setattr(app, "run_training", lambda experiment, out, **_: handed.append(experiment))
    config = tmp_path / "exp.py"
    config.write_text("from jaxanom.app.experiment import Experiment\nfrom jaxanom.train.segmenter import TrainConfig\n"
                      "from jaxanom.cudam.objective import CuDAM\n"
                      "experiment = Experiment(train=TrainConfig(run_dir='', objective=CuDAM(beta=0.25)))\n")
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "a"), "--no-progress"]) == 2
    error = capsys.readouterr().err.strip()
    assert "attention and train.objective disagree" in error and len(error.splitlines()) == 1, error
    assert not (tmp_path / "a").exists() and handed == []
    # --attention cudam keeps the config's CuDAM settings; --attention none replaces them
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "b"), "--attention", "cudam",
                 "--cudam-tau", "7", "--no-progress"]) == 0
    assert handed[-1].train.objective == CuDAM(beta=0.25, tau=7.0)
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "c"), "--attention", "none",
                 "--no-progress"]) == 0
    assert handed[-1].attention is None and handed[-1].train.objective == CrossEntropy()
    assert main(["train", "--out", str(tmp_path / "d"), "--cudam-tau", "7", "--no-progress"]) == 2
    assert "--cudam-tau: the objective is 'cross_entropy'" in capsys.readouterr().err


def test_experiment_json_of_the_earlier_version_loads_as_the_same_training(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "experiment.json").write_text(json.dumps(LEGACY))
    experiment = load_experiment(run)
    # the plain loss on a CuDAM network: the CuDAM objective without its terms (the same program)
    assert experiment.attention == "cudam" and experiment.train.objective == CuDAM(tau=5e4, reward_prob=0.0, beta=0.0)
    assert (experiment.train.ignore, experiment.train.compute_dtype) == (255, "float32")
    check_objective(experiment)
    check_same_run(experiment, experiment, run)

    def legacy(attention, **loss):
        values = copy.deepcopy(LEGACY)
        values["attention"] = attention
        values["train"]["loss"].update(loss)
        return decode(Experiment, values).train

    cudam = legacy("cudam", method="cudam", tau=7.0, beta=0.3, attention_literal=True, class_weights=[1, 2],
                   compute_dtype="bfloat16", ignore=250)
    assert cudam.objective == CuDAM(tau=7.0, beta=0.3, attention_literal=True, class_weights=(1, 2))
    assert (cudam.compute_dtype, cudam.ignore) == ("bfloat16", 250)
    assert legacy("msaam", method="msaam", msaam_lambda=0.2, msaam_literal=True).objective == MSAAM(0.2, True)
    assert legacy("msaam").objective == MSAAM(lam=0.0)
    assert legacy(None, class_weights=[0.5] * 19).objective == CrossEntropy((0.5,) * 19)
    with pytest.raises(ValueError, match="attention_k='running_sml' keeps its statistics in checkpoints"):
        legacy("cudam", method="cudam", attention_k="running_sml")


def test_a_different_experiment_names_the_field_and_steps_grow_only_on_a_flat_schedule(tmp_path):
    stored = Experiment(train=TrainConfig(run_dir="", steps=6))
    with pytest.raises(ValueError, match=r"holds a run of a different experiment: train.optim.lr is 0.01 there, "
                                         r"0.02 here; resume continues that run with its own settings"):
        check_same_run(stored, dataclasses.replace(stored, train=dataclasses.replace(
            stored.train, optim=OptimConfig(lr=0.02))), tmp_path)
    with pytest.raises(ValueError, match=r"different experiment: attention is None there, 'cudam' here \(and 1 more\)"):
        check_same_run(stored, dataclasses.replace(stored, batch_size=4, attention="cudam"), tmp_path)
    longer = dataclasses.replace(stored, train=dataclasses.replace(stored.train, steps=9))
    check_same_run(stored, longer, tmp_path)  # no checkpoint yet: no step was trained on the old schedule
    with Checkpointer(tmp_path / "checkpoints") as checkpointer:
        checkpointer.save(6, {"x": np.zeros(2, np.float32)})
    with pytest.raises(ValueError, match=r"train.steps: the run in .* has 6 steps and its learning rate decays to 0 "
                                         r"at the last one \(poly_power 0.9\), so 9 steps would not continue it"):
        check_same_run(stored, longer, tmp_path)
    flat = dataclasses.replace(stored.train, optim=OptimConfig(poly_power=0.0))
    check_same_run(dataclasses.replace(stored, train=flat),
                   dataclasses.replace(stored, train=dataclasses.replace(flat, steps=9)), tmp_path)
    with pytest.raises(ValueError, match=r"train.steps: expected at least the 6 steps the run in .* has trained, got 5"):
        check_same_run(dataclasses.replace(stored, train=flat),
                       dataclasses.replace(stored, train=dataclasses.replace(flat, steps=5)), tmp_path)
