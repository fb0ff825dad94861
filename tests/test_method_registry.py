"""The scoring-method registry: names, needs, options, plug-ins from outside the package (``--plugin``
and the ``jaxanom.methods`` entry points) scored through ``score``, ``evaluate`` and ``predict``."""
import json
import sys

import cv2
import numpy as np
import pytest

from jaxanom import method_registry
from jaxanom.cli import main
from jaxanom.cudam.score import paper_sigma
from converted_run import SIZE, tiny_run  # noqa: F401  (the fixture)

PLUGIN = """
import jax.numpy as jnp
from jaxanom.method_registry import Method, register

register(Method("{name}", frozenset({{"logits"}}),
                lambda inputs, options: -options["scale"] * jnp.max(jnp.asarray(inputs["logits"]), axis=-1),
                "a test's throw-away method: scale times the negative max logit", defaults={{"scale": 2.0}}))
"""


@pytest.fixture(scope="module")
def road_anomaly(tmp_path_factory):
    """A Road Anomaly folder of one random frame at the tiny run's working size, a square anomaly in it."""
    root = tmp_path_factory.mktemp("road_anomaly")
    (root / "frames" / "f.labels").mkdir(parents=True)
    (root / "frame_list.json").write_text('["f.png"]')
    cv2.imwrite(str(root / "frames" / "f.png"), np.random.default_rng(0).integers(0, 256, (*SIZE, 3), np.uint8))
    label = np.zeros(SIZE, np.uint8)
    label[10:30, 20:50] = 2
    cv2.imwrite(str(root / "frames" / "f.labels" / "labels_semantic.png"), label)
    return root


@pytest.fixture
def registry_state(monkeypatch):
    """The registry as it was before the test (a plug-in's methods and modules do not outlive it)."""
    method_registry.names()
    monkeypatch.setattr(method_registry.METHODS, "entries", dict(method_registry.METHODS.entries))
    monkeypatch.setattr(method_registry.METHODS, "origins", dict(method_registry.METHODS.origins))
    modules = set(sys.modules)
    yield
    for name in set(sys.modules) - modules:
        if name.startswith("jaxanom_test_plugin"):
            del sys.modules[name]


@pytest.fixture
def plugin(tmp_path, monkeypatch, registry_state):
    """A plug-in module outside the package, on sys.path; its method is ``twice_max_logit``."""
    folder = tmp_path / "plugins"
    folder.mkdir()
    (folder / "jaxanom_test_plugin.py").write_text(PLUGIN.format(name="twice_max_logit"))
    monkeypatch.syspath_prepend(str(folder))
    return "jaxanom_test_plugin"


def test_every_paper_registers_its_rows():
    assert {"msp", "max_logit", "entropy", "energy", "softmax_distance", "sml", "sml_suppress", "sml_smooth",
            "sml_post", "msp_post", "max_logit_post", "cudam", "mmf_raw", "mmf", "resynthesis", "resynthesis_post",
            "entropy_superpixel", "softmax_distance_superpixel"} <= set(method_registry.names())
    for name in method_registry.names():
        method = method_registry.get(name)
        assert method.name == name and method.needs <= set(method_registry.INPUTS) and method.description


def test_unknown_methods_are_named_with_the_known_ones():
    with pytest.raises(ValueError) as error:
        method_registry.check(["msp", "bogus"], {"logits"})
    assert "'bogus'" in str(error.value) and "max_logit" in str(error.value) and "\n" not in str(error.value)
    with pytest.raises(ValueError, match="'nope'"):
        method_registry.get("nope")
    with pytest.raises(ValueError, match="expected names"):
        method_registry.check([], {"logits"})


def test_a_missing_input_is_named_in_one_line_with_the_methods_needing_it():
    with pytest.raises(ValueError) as error:
        method_registry.check(["msp", "sml", "cudam"], {"logits", "attention"})
    assert str(error.value) == ("methods ['sml', 'cudam'] need SML class statistics (mean, std), each (C,); "
                                "none were given")
    with pytest.raises(ValueError, match=r"methods \['cudam'\] need an attention map"):
        method_registry.check(["cudam"], {"logits", "stats"})
    assert method_registry.check(["cudam", "msp"], {"logits", "stats", "attention"}) == ("cudam", "msp")
    with pytest.raises(ValueError, match=r"methods \['sml'\] need SML"):  # a None value is not an input
        method_registry.score("sml", {"logits": np.zeros((1, 2, 2, 3)), "stats": None})


def test_options_are_declared_defaulted_and_resolved():
    provided = {"logits", "stats", "attention"}
    with pytest.raises(ValueError, match=r"^options: methods.cudam.sigma: method 'cudam' has no option 'sigma'; its "
                                         r"options: cudam_sigma$"):
        method_registry.check(["cudam"], provided, {"cudam": {"sigma": 1.0}})
    with pytest.raises(ValueError, match=r"^options: methods.cudam.cudam_sigma: expected a number or none, got 'x'$"):
        method_registry.check(["cudam"], provided, {"cudam": {"cudam_sigma": "x"}})
    with pytest.raises(ValueError, match=r"^options: options of \['msp'\], which are not among the methods \['cudam'\]$"):
        method_registry.check(["cudam"], provided, {"msp": {}})
    assert method_registry.get("cudam").checked({"cudam_sigma": 3}) == {"cudam_sigma": 3.0}  # read as its type
    assert method_registry.get("cudam").types["cudam_sigma"] == float | None
    cudam = method_registry.get("cudam")
    positions = {"attention_positions": np.int32(32 * 64)}
    assert cudam.options(positions) == {"cudam_sigma": paper_sigma(32 * 64)}  # the paper-equivalent default
    assert cudam.options(positions, {"cudam_sigma": None}) == {"cudam_sigma": paper_sigma(32 * 64)}
    assert cudam.options({}, {"cudam_sigma": 3.0, "slic_step": 4}) == {"cudam_sigma": 3.0}
    with pytest.raises(ValueError, match="attention_positions"):
        cudam.options({})
    step = method_registry.get("entropy_superpixel")
    assert step.options({"logits": np.zeros((1, 256, 512, 3))}) == {"slic_step": 8}  # superpixels.scaled_step


def test_cudam_scores_with_its_resolved_sigma():
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(2, 6, 10, 4)).astype(np.float32)
    stats = (rng.normal(size=4).astype(np.float32), rng.uniform(0.5, 2, size=4).astype(np.float32))
    attention = rng.uniform(size=(2, 6, 10)).astype(np.float32) / 60
    inputs = {"logits": logits, "stats": stats, "attention": attention, "attention_positions": 15}
    sml_post = np.asarray(method_registry.score("sml_post", inputs))
    np.testing.assert_allclose(method_registry.score("cudam", inputs),
                               sml_post + np.float32(paper_sigma(15)) * attention, rtol=1e-6)
    np.testing.assert_allclose(method_registry.score("cudam", inputs, {"cudam_sigma": 7.0}),
                               sml_post + 7 * attention, rtol=1e-6)


def test_a_name_cannot_be_taken_twice_and_methods_are_checked(registry_state):
    msp = method_registry.get("msp")
    assert method_registry.register(msp) is msp  # the same method again (a module imported twice)
    with pytest.raises(ValueError, match="'msp': already registered by jaxanom.score_methods"):
        method_registry.register(method_registry.Method("msp", frozenset({"logits"}), lambda i, o: 0, "another"))
    with pytest.raises(ValueError, match=r"needs of x: expected keys of INPUTS .*got \['pictures'\]"):
        method_registry.Method("x", frozenset({"logits", "pictures"}), lambda i, o: 0, "x")
    with pytest.raises(ValueError, match="description of x: expected one line"):
        method_registry.Method("x", frozenset({"logits"}), lambda i, o: 0, "two\nlines")
    with pytest.raises(ValueError, match="name: expected"):
        method_registry.Method("a,b", frozenset({"logits"}), lambda i, o: 0, "x")


def test_installed_packages_register_through_entry_points(tmp_path, monkeypatch, registry_state):
    site = tmp_path / "site"
    (site / "jaxanom_test_plugin_dist-1.0.dist-info").mkdir(parents=True)
    (site / "jaxanom_test_plugin_dist-1.0.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: jaxanom-test-plugin-dist\nVersion: 1.0\n")
    (site / "jaxanom_test_plugin_dist-1.0.dist-info" / "entry_points.txt").write_text(
        "[jaxanom.methods]\nmine = jaxanom_test_plugin_ep\n")
    (site / "jaxanom_test_plugin_ep.py").write_text(PLUGIN.format(name="from_entry_point"))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(method_registry.METHODS, "loaded", False)
    assert method_registry.names()[-1] == "from_entry_point"
    logits = np.random.default_rng(0).normal(size=(1, 3, 4, 5)).astype(np.float32)
    np.testing.assert_array_equal(method_registry.score("from_entry_point", {"logits": logits}),
                                  -2 * logits.max(-1))

    (site / "jaxanom_test_plugin_ep.py").write_text("raise RuntimeError('broken plug-in')\n")
    del sys.modules["jaxanom_test_plugin_ep"]
    monkeypatch.setattr(method_registry.METHODS, "loaded", False)
    monkeypatch.setattr(method_registry.METHODS, "entries", {
        k: v for k, v in method_registry.METHODS.entries.items() if k != "from_entry_point"})
    assert "msp" in method_registry.names() and "from_entry_point" not in method_registry.names()  # left out
    with pytest.raises(ValueError, match="got unknown 'from_entry_point'; the jaxanom.methods entry point mine = "
                                         r"jaxanom_test_plugin_ep \(jaxanom-test-plugin-dist\) failed to load "
                                         r"\(RuntimeError: broken plug-in\)"):
        method_registry.get("from_entry_point")


def test_a_plugin_method_through_score(tmp_path, plugin):
    logits = np.random.default_rng(0).normal(size=(2, 5, 6, 7)).astype(np.float32)  # NCHW
    labels = (np.arange(2 * 6 * 7).reshape(2, 6, 7) % 3 == 0).astype(np.uint8)
    np.save(tmp_path / "logits.npy", logits)
    np.save(tmp_path / "labels.npy", labels)
    out = tmp_path / "out"
    assert main(["score", "--logits", str(tmp_path / "logits.npy"), "--labels", str(tmp_path / "labels.npy"),
                 "--plugin", plugin, "--methods", "twice_max_logit,max_logit", "--out", str(out)]) == 0
    np.testing.assert_array_equal(np.load(out / "scores" / "twice_max_logit.npy"), -2 * logits.max(axis=1))
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    assert metrics["twice_max_logit"]["ap"] == metrics["max_logit"]["ap"]  # a positive scale keeps the ranking


def test_a_plugin_method_and_the_superpixel_methods_through_evaluate_and_predict(
        tmp_path, plugin, tiny_run, road_anomaly):  # noqa: F811
    from jaxanom.app.evaluate import predictor
    from jaxanom.app.experiment import build_network, load_variables
    from jaxanom.data import RoadAnomaly
    from jaxanom.metrics import anomaly_metrics

    out = tmp_path / "evaluate"
    superpixel = ("entropy_superpixel", "softmax_distance_superpixel")  # evaluate has the images: it gives them
    assert main(["evaluate", "--run", str(tiny_run), "--dataset", "road-anomaly", "--path", str(road_anomaly),
                 "--plugin", plugin, "--methods", ",".join(("max_logit", "twice_max_logit", *superpixel)),
                 "--track", "none", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    assert metrics["twice_max_logit"]["options"] == {"scale": [2.0]}
    for key in ("ap", "auroc", "fpr_at_tpr"):
        assert metrics["twice_max_logit"][key] == metrics["max_logit"][key]
    frame = RoadAnomaly(road_anomaly)[0]
    experiment, variables = load_variables(tiny_run)
    logits = predictor(build_network(experiment), variables)(frame["image"][None])["logits"]
    for name in superpixel:  # the method's scores of the frame's own image
        expected = anomaly_metrics(method_registry.score(name, {"logits": logits, "image": frame["image"][None]}),
                                   frame["label"][None])
        assert metrics[name]["ap"] == expected["ap"] and metrics[name]["auroc"] == expected["auroc"]
        assert metrics[name]["options"] == {"slic_step": [2]}  # superpixels.scaled_step of 48 x 96

    out = tmp_path / "predict"
    assert main(["predict", str(road_anomaly / "frames" / "f.png"), "--run", str(tiny_run), "--plugin", plugin,
                 "--methods", "max_logit,twice_max_logit", "--out", str(out), "--no-progress"]) == 0
    np.testing.assert_array_equal(np.load(out / "npy" / "twice_max_logit" / "f.npy"),
                                  2 * np.load(out / "npy" / "max_logit" / "f.npy"))  # x2 is exact in float16


def test_an_unknown_plugin_or_method_is_one_line(tmp_path, capsys, plugin):
    np.save(tmp_path / "l.npy", np.zeros((1, 3, 4, 5), np.float32))
    args = ["score", "--logits", str(tmp_path / "l.npy"), "--out", str(tmp_path / "o")]
    assert main([*args, "--plugin", "no_such_module_xyz"]) == 2
    error = capsys.readouterr().err.strip()
    assert error == "jaxanom score: error: --plugin no_such_module_xyz: no module named 'no_such_module_xyz' on the " \
                    "Python path"
    assert main([*args, "--methods", "twice_max_logit"]) == 2  # without its plug-in the method is unknown
    error = capsys.readouterr().err.strip()
    assert "'twice_max_logit'" in error and "msp" in error and len(error.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_help_lists_every_method_with_its_description(capsys):
    for command in ("evaluate", "predict", "score"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        lines = capsys.readouterr().out.splitlines()
        assert any("--plugin MODULE" in line for line in lines)
        for name in method_registry.names():
            if command == "predict" and "mmf_maps" in method_registry.get(name).needs:
                assert not any(line.split()[:1] == [name] for line in lines)  # predict has no MMF pipeline
                continue
            description = method_registry.get(name).description
            assert any(line.split()[:len(description.split()) + 1] == [name, *description.split()]
                       for line in lines), (command, name)
    assert any("entropy_superpixel" in line and line.endswith("(options slic_step: an integer or none, default None)")
               for line in lines)
