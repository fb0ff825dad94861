"""Options as data: every method declares its options' types and defaults, and the commands set any
of them one way, ``--set methods.NAME.OPTION=VALUE`` (``--cudam-sigma`` and ``--slic-step`` being
aliases of the same options), checked against the declared type in one line naming the method
and option; predict's resume key holds every option, so a changed one never keeps old maps."""
import json

import numpy as np
import pytest

from jaxanom.cli import main
from converted_run import tiny_run  # noqa: F401  (the module fixture: a tiny converted run)
from test_method_registry import registry_state, road_anomaly  # noqa: F401  (fixtures)
from test_plugin_safety import forget, logits_file, one_line_error, registering, run_predict, write_images, write_module

TEMPERATURE = "-options['temperature'] * jnp.max(jnp.asarray(inputs['logits']), axis=-1)"


@pytest.fixture
def temp_plugin(tmp_path, monkeypatch, registry_state):  # noqa: F811
    """A plug-in registering ``temp``: temperature (default 1) times the negative max logit."""
    return write_module(tmp_path / "plugins", "p_options", registering("temp", TEMPERATURE, {"temperature": 1.0}),
                        monkeypatch)


def test_score_sets_a_plugins_option_and_records_it(tmp_path, capsys, temp_plugin):
    argv = [*logits_file(tmp_path), "--plugin", temp_plugin, "--methods", "temp"]
    assert main([*argv, "--out", str(tmp_path / "one")]) == 0
    assert main([*argv, "--set", "methods.temp.temperature=3", "--out", str(tmp_path / "three")]) == 0
    one, three = (np.load(tmp_path / name / "scores" / "temp.npy") for name in ("one", "three"))
    np.testing.assert_allclose(three, 3 * one, rtol=1e-6)
    assert json.loads((tmp_path / "three" / "metrics.json").read_text())["metrics"]["temp"]["options"] == {
        "temperature": 3.0}


@pytest.mark.parametrize("assignment, expected", [
    ("methods.temp.temperature=hot", "--set methods.temp.temperature: expected a number, got 'hot' (an option of "
                                     "method 'temp')"),
    ("methods.temp.warmth=2", "--set methods.temp.warmth: method 'temp' has no option 'warmth'; its options: "
                              "temperature"),
    ("methods.msp.temperature=2", "--set methods.msp.temperature: method 'msp' has no option 'temperature'; its "
                                  "options: none"),
    ("methods.energy.temperature=2", "--set methods.energy.temperature: method 'energy' is not among the methods "
                                     "scored (temp, msp; --methods)"),
    ("methods.temp=2", "--set: expected methods.METHOD.OPTION=VALUE (e.g. methods.energy.temperature=2), got "
                       "'methods.temp=2'"),
    ("size=12,12", "--set size=12,12: score sets options of the methods only: methods.METHOD.OPTION=VALUE"),
])
def test_a_bad_option_is_one_line_naming_the_method_and_option(tmp_path, capsys, temp_plugin, assignment, expected):
    error = one_line_error(capsys, [*logits_file(tmp_path), "--plugin", temp_plugin, "--methods", "temp,msp", "--set",
                                    assignment, "--out", str(tmp_path / "o")])
    assert error == f"jaxanom score: error: {expected}", error
    assert not (tmp_path / "o").exists()


def test_evaluate_sets_options_and_refuses_a_bad_one_before_any_work(tiny_run, tmp_path, capsys, road_anomaly,  # noqa: F811
                                                                    temp_plugin):
    argv = ["evaluate", "--run", str(tiny_run), "--dataset", "road-anomaly", "--path", str(road_anomaly), "--plugin",
            temp_plugin, "--methods", "temp", "--no-progress"]
    assert main([*argv, "--set", "methods.temp.temperature=2.5", "--out", str(tmp_path / "e")]) == 0
    record = json.loads((tmp_path / "e" / "metrics.json").read_text())
    assert record["metrics"]["temp"]["options"] == {"temperature": [2.5]}
    error = one_line_error(capsys, [*argv, "--set", "methods.temp.temperature=[1]", "--out", str(tmp_path / "f")])
    assert error.endswith("--set methods.temp.temperature: expected a number, got [1] (an option of method 'temp')")
    assert not (tmp_path / "f").exists()


def test_predict_recomputes_or_refuses_maps_of_another_option(tiny_run, tmp_path, capsys, temp_plugin):  # noqa: F811
    images, out = write_images(tmp_path / "images", 1), tmp_path / "maps"
    assert run_predict(capsys, images, tiny_run, out, temp_plugin, "temp")[0] == 0
    first = np.load(out / "npy" / "temp" / "f0.npy")
    forget(temp_plugin, "temp")
    code, text = run_predict(capsys, images, tiny_run, out, temp_plugin, "temp", "--set", "methods.temp.temperature=4")
    assert code == 2 and ("holds maps of method 'temp' made with options {'temperature': 1.0}, now {'temperature': "
                          "4.0}") in text, text
    np.testing.assert_array_equal(np.load(out / "npy" / "temp" / "f0.npy"), first)
    forget(temp_plugin, "temp")
    code, text = run_predict(capsys, images, tiny_run, out, temp_plugin, "temp", "--set", "methods.temp.temperature=4",
                             "--overwrite")
    assert code == 0 and "1 frames written, 0 already there" in text, text
    np.testing.assert_array_equal(np.load(out / "npy" / "temp" / "f0.npy"), 4 * first)  # x4 is exact in float16
    record = json.loads((out / "settings.json").read_text())
    assert record["method_code"]["temp"]["options"] == {"temperature": 4.0}


def test_slic_step_is_an_alias_of_the_option(tiny_run, tmp_path, capsys):  # noqa: F811
    images, out = write_images(tmp_path / "images", 1), tmp_path / "maps"
    argv = ["predict", str(images), "--run", str(tiny_run), "--out", str(out), "--methods", "entropy_superpixel",
            "--no-progress"]
    assert main([*argv, "--slic-step", "6"]) == 0
    assert json.loads((out / "settings.json").read_text())["method_code"]["entropy_superpixel"]["options"] == {
        "slic_step": 6}
    capsys.readouterr()
    assert main([*argv, "--set", "methods.entropy_superpixel.slic_step=6"]) == 0  # the same maps: resumed
    assert "0 frames written, 1 already there" in capsys.readouterr().out
    error = one_line_error(capsys, [*argv, "--set", "methods.entropy_superpixel.slic_step=2.5"])
    assert error.endswith("--set methods.entropy_superpixel.slic_step: expected an integer or none, got '2.5' (an "
                          "option of method 'entropy_superpixel')"), error


@pytest.mark.parametrize("command, own, foreign", [
    ("predict", "set one of predict's settings by its name", "train.optim.lr"),
    ("evaluate", "methods.METHOD.OPTION=VALUE sets an option of a method", "train.optim.lr"),
    ("score", "methods.METHOD.OPTION=VALUE sets an option of a method", "train.optim.lr"),
    ("train", "set one field of the configuration by its dotted name", "methods.METHOD.OPTION"),
])
def test_every_help_describes_its_own_set_and_takes_no_progress(capsys, command, own, foreign):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert own in text and foreign not in text and "--no-progress" in text
