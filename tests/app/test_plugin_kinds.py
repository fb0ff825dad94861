"""Extending jaxanom as its users do: an outside package registers a scoring method with an option
and a training objective; a run trained with them records the package, so resuming it, training
again from its experiment.json, fitting its statistics, evaluating it and predicting with it all
work without naming the package again, whether it came by ``--plugin`` or by entry points; a
run whose package is gone stops in one line naming it."""
import json
import sys
import textwrap

import cv2
import numpy as np
import pytest

from jaxanom import method_registry, objectives, registry
from jaxanom.cli import main

PACKAGE = "jaxanom_test_ext"
EXTENSION = '''
    """An extension author's package: a method with an option, and an objective."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    from jaxanom.method_registry import Method, register
    from jaxanom.objectives import Objective, register as register_objective


    def temp_energy(inputs, options):  # (B, H, W, C) -> (B, H, W): -T logsumexp(logits / T)
        t = options["temperature"]
        return -t * jax.nn.logsumexp(jnp.asarray(inputs["logits"], jnp.float32) / t, axis=-1)


    register(Method("temp_energy", frozenset({"logits"}), temp_energy, "temperature-scaled energy",
                    defaults={"temperature": 1.0}))


    @register_objective
    @dataclasses.dataclass(frozen=True)
    class Focal(Objective):
        """Focal loss: -(1 - p_y)^gamma log p_y over the valid pixels."""

        gamma: float = 2.0
        name: str = dataclasses.field(default="focal", init=False)

        def loss(self, outputs, batch, key, state, ignore):
            labels = batch["label"]
            valid = labels != ignore
            log_p = jax.nn.log_softmax(outputs["logits"].astype(jnp.float32), axis=-1)
            log_py = jnp.take_along_axis(log_p, jnp.where(valid, labels, 0)[..., None], axis=-1)[..., 0]
            loss = jnp.where(valid, -(1 - jnp.exp(log_py)) ** self.gamma * log_py, 0.0)
            return loss.sum() / jnp.maximum(valid.sum(), 1), {}, state
'''
# a tiny experiment: 2 steps of a tiny network on small synthetic frames; a flat schedule, so it may grow
CONFIG = {"train_frames": 4, "height": 32, "width": 64, "crop": [32, 64], "batch_size": 4,
          "train": {"steps": 2, "objective": {"name": "focal", "gamma": 1.5}, "save_every": 1, "log_every": 1,
                    "eval_every": 1000, "optim": {"poly_power": 0.0, "warmup_steps": 0}}}


@pytest.fixture
def extension(tmp_path, monkeypatch):
    """The package on sys.path (a folder ``site``); every registry restored after the test."""
    site = tmp_path / "site"
    (site / PACKAGE).mkdir(parents=True)
    (site / PACKAGE / "__init__.py").write_text(textwrap.dedent(EXTENSION))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    for kind in registry._ALL:
        kind.names()
        for attribute in ("entries", "origins"):
            monkeypatch.setattr(kind, attribute, dict(getattr(kind, attribute)))
    yield site
    forget()


def forget():
    """As a new process finds them: the package not imported, its names not registered, the entry
    points not read."""
    sys.modules.pop(PACKAGE, None)
    for kind in registry._ALL:
        kind.loaded = False
        for name in [name for name, origin in kind.origins.items() if origin == PACKAGE]:
            del kind.entries[name], kind.origins[name]


def command(capsys, *argv):
    """Run ``jaxanom argv`` as a new process would (the package not imported yet); its exit status
    and output."""
    forget()
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def images(folder):
    folder.mkdir()
    for index in range(2):
        cv2.imwrite(str(folder / f"f{index}.png"), np.random.default_rng(index).integers(0, 256, (32, 64, 3), np.uint8))
    return folder


def through_every_command(capsys, tmp_path, plugin: tuple[str, ...]):
    """train -> train --resume -> train --config RUN/experiment.json -> fit-stats -> evaluate ->
    predict with the package's objective and method; ``plugin``: the flags naming the package at
    train, evaluate and predict (none: it comes by entry points). Returns the run folder."""
    config, run = tmp_path / "config.json", tmp_path / "run"
    config.write_text(json.dumps(CONFIG))
    code, text = command(capsys, "train", "--config", config, "--out", run, "--no-progress", *plugin)
    assert code == 0, text
    recorded = json.loads((run / "experiment.json").read_text())
    assert recorded["plugins"] == [PACKAGE] and recorded["train"]["objective"] == {"gamma": 1.5, "name": "focal"}

    code, text = command(capsys, "train", "--resume", "--out", run, "--set", "train.steps=3", "--no-progress")
    assert code == 0 and "trained 3 steps" in text, text
    code, text = command(capsys, "train", "--config", run / "experiment.json", "--out", tmp_path / "again",
                         "--set", "train.steps=1", "--set", "train.objective.gamma=3", "--no-progress")
    assert code == 0, text
    again = json.loads((tmp_path / "again" / "experiment.json").read_text())
    assert again["plugins"] == [PACKAGE] and again["train"]["objective"]["gamma"] == 3

    stats = tmp_path / "stats.npz"
    code, text = command(capsys, "fit-stats", "--run", run, "--out", stats, "--frames", 2, "--missing", "pooled")
    assert code == 0, text
    code, text = command(capsys, "evaluate", "--run", run, "--dataset", "synthetic", "--path", "anomaly", "--frames", 2,
                         "--stats", stats, "--methods", "msp,temp_energy,sml", "--out", tmp_path / "eval", *plugin)
    assert code == 0, text
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())["metrics"]
    assert metrics["temp_energy"]["options"] == {"temperature": [1.0]}
    code, text = command(capsys, "predict", images(tmp_path / "images"), "--run", run, "--methods", "temp_energy",
                         "--out", tmp_path / "maps", "--no-progress", *plugin)
    assert code == 0 and "2 frames written" in text, text
    assert np.load(tmp_path / "maps" / "npy" / "temp_energy" / "f0.npy").shape == (32, 64)
    return run


@pytest.mark.end_to_end
def test_an_outside_objective_and_method_through_every_command_by_plugin_flag(tmp_path, capsys, extension):
    code, text = command(capsys, "train", "--set", "train.objective=focal", "--out", tmp_path / "no", "--no-progress")
    assert code == 2 and "got 'focal' (an objective of a plug-in: import its module first" in text, text
    run = through_every_command(capsys, tmp_path, ("--plugin", PACKAGE))

    (extension / PACKAGE / "__init__.py").unlink()  # the package uninstalled: every reading names it, in one line
    (extension / PACKAGE).rmdir()
    for argv in (("train", "--resume", "--out", run, "--no-progress"),
                 ("fit-stats", "--run", run, "--out", tmp_path / "s2.npz", "--frames", 2),
                 ("evaluate", "--run", run, "--dataset", "synthetic", "--path", "anomaly", "--frames", 2,
                  "--methods", "msp", "--out", tmp_path / "e2"),
                 ("predict", tmp_path / "images", "--run", run, "--methods", "msp", "--out", tmp_path / "m2")):
        code, text = command(capsys, *argv)
        assert code == 2 and len(text.strip().splitlines()) == 1, text
        assert (f"plugins: the plug-in module '{PACKAGE}' that registers what this config names could not be "
                f"imported (no module named '{PACKAGE}' on the Python path); install it") in text, text


@pytest.mark.end_to_end
def test_an_outside_objective_and_method_through_every_command_by_entry_points(tmp_path, capsys, monkeypatch,
                                                                               extension):
    info = extension / "jaxanom_test_ext_dist-1.0.dist-info"  # an installed distribution declaring both
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: jaxanom-test-ext\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[jaxanom.methods]\ntemp = {PACKAGE}\n"
                                           f"[jaxanom.objectives]\nfocal = {PACKAGE}\n")
    for kind in registry._ALL:
        monkeypatch.setattr(kind, "loaded", False)  # entry points read again on next use
    through_every_command(capsys, tmp_path, ())


def test_a_python_config_defining_its_objective_is_refused_before_any_work(tmp_path, capsys, monkeypatch, extension):
    import jaxanom.app.experiment as app

    monkeypatch.setattr(app, "run_training", lambda *_, **__: None)  # should it not be refused: no training
    config = tmp_path / "config.py"
    config.write_text(textwrap.dedent('''
        import dataclasses
        from jaxanom.app.experiment import Experiment
        from jaxanom.losses import CrossEntropy
        from jaxanom.objectives import register
        from jaxanom.train.segmenter import TrainConfig

        @register
        @dataclasses.dataclass(frozen=True)
        class Inline(CrossEntropy):
            name: str = dataclasses.field(default="jaxanom_test_inline", init=False)

        experiment = Experiment(train=TrainConfig(run_dir="", objective=Inline()))
        '''))
    try:
        code, text = command(capsys, "train", "--config", config, "--out", tmp_path / "run", "--no-progress")
    finally:
        objectives.OBJECTIVES.entries.pop("jaxanom_test_inline", None)
    assert code == 2 and len(text.strip().splitlines()) == 1, text
    assert "--config: objective 'jaxanom_test_inline' is registered by <run_path>, which later readings" in text, text
    assert not (tmp_path / "run").exists()


def test_one_registry_type_names_every_kind_and_refuses_a_taken_or_bad_name(extension):
    assert {kind.group for kind in registry._ALL} >= {"jaxanom.methods", "jaxanom.objectives"}
    registry.load_plugin(PACKAGE)
    assert method_registry.METHODS.plugin_module("temp_energy") == PACKAGE
    assert objectives.OBJECTIVES.plugin_module("focal") == PACKAGE
    assert objectives.OBJECTIVES.plugin_module("cudam") is None
    with pytest.raises(ValueError, match=r"^objective 'cudam': already registered by CuDAM \(jaxanom.cudam.objective\); "
                                         r"\S+ cannot register another under the same name$"):
        objectives.register(_renamed("cudam"))
    with pytest.raises(ValueError, match=r"^objective name: expected letters, digits, '_', '-', '.' \(not '.' or "
                                         r"'..'\), got '../focal'$"):
        objectives.register(_renamed("../focal"))


def _renamed(name):
    """A copy of the package's objective registered under ``name``."""
    import dataclasses

    focal = objectives.Objective.class_named("focal")
    return dataclasses.dataclass(frozen=True)(type("Renamed", (focal,), {
        "__annotations__": {"name": str}, "name": dataclasses.field(default=name, init=False)}))


def test_a_run_records_its_plugins_and_every_reading_imports_them(tmp_path, capsys, monkeypatch, extension):
    """Without training (the end-to-end tests above train): what train hands the run, and what a
    later reading of its experiment.json does."""
    import jaxanom.app.experiment as app

    handed = []
    monkeypatch.setattr(app, "run_training", lambda experiment, out, **_: handed.append(experiment))
    code, text = command(capsys, "train", "--plugin", PACKAGE, "--set", "train.objective=focal", "--out",
                         tmp_path / "run", "--no-progress")
    assert code == 0, text
    assert handed[-1].plugins == (PACKAGE,) and handed[-1].train.objective.name == "focal"
    run = tmp_path / "run"
    (run / "experiment.json").write_text(json.dumps(app.jsonable(handed[-1])))

    forget()  # a new process: the recorded module is imported when the run is read
    assert type(app.load_experiment(run).train.objective).__module__ == PACKAGE
    assert PACKAGE in sys.modules and "temp_energy" in method_registry.names()

    (extension / PACKAGE / "__init__.py").unlink()  # uninstalled
    (extension / PACKAGE).rmdir()
    code, text = command(capsys, "evaluate", "--run", run, "--dataset", "synthetic", "--path", "anomaly",
                         "--out", tmp_path / "eval")
    assert code == 2 and text.strip() == (
        f"jaxanom evaluate: error: --run {run}: {run / 'experiment.json'}: plugins: the plug-in module '{PACKAGE}' "
        f"that registers what this config names could not be imported (no module named '{PACKAGE}' on the Python "
        "path); install it or put it on PYTHONPATH"), text


@pytest.mark.parametrize("argv", [
    ["train", "--out", "{tmp}/o"], ["fit-stats", "--run", "{tmp}/run", "--out", "{tmp}/s.npz"],
    ["evaluate", "--run", "{tmp}/run", "--dataset", "synthetic", "--path", "anomaly", "--out", "{tmp}/o"],
    ["predict", "{tmp}", "--run", "{tmp}/run", "--out", "{tmp}/o"], ["score", "--logits", "{tmp}/l.npy", "--out", "{tmp}/o"],
    ["demo", "--out", "{tmp}/o"]], ids=lambda argv: argv[0])
def test_every_command_resolving_names_takes_plugin_and_names_a_missing_one(tmp_path, capsys, argv):
    code, text = command(capsys, *(arg.format(tmp=tmp_path) for arg in argv), "--plugin", "jaxanom_test_absent")
    assert code == 2 and text.strip().endswith(
        "error: --plugin jaxanom_test_absent: no module named 'jaxanom_test_absent' on the Python path"), text
    assert not (tmp_path / "o").exists()
