"""What a plug-in cannot do to the commands: a method's name is never a path, and nothing is
written or removed outside ``--out``; what a method returns is checked at one boundary (shape,
floating dtype, finite values) with its name in the message, in ``score``, ``evaluate`` and
``predict`` alike; methods get read-only inputs; a broken plug-in is one line; and ``predict``
never resumes maps made by other code or options of a method."""
import json
import re
import sys
import textwrap

import cv2
import h5py
import numpy as np
import pytest

from jaxanom import method_registry
from jaxanom.app.evaluate import anomaly_results
from jaxanom.app.predict import PredictSettings, Scorer, predict_images
from jaxanom.cli import main
from jaxanom.errors import InputError
from converted_run import SIZE, tiny_run  # noqa: F401  (the module fixture: a tiny converted run)
from test_method_registry import registry_state, road_anomaly  # noqa: F401  (fixtures: the registry restored
# after a test; a Road Anomaly folder of one frame at the tiny run's SIZE)

B, H, W, C = 2, 6, 8, 5

# Methods returning each kind of output the boundary refuses, and what the message says of it (a
# regular expression: score scores one image at a time, evaluate batches of B).
BAD_OUTPUTS = {
    "transposed": ("jnp.swapaxes(logits[..., 0], 1, 2)", r"shape \(\d, 8, 6\); expected \(B, H, W\) = \(\d, 6, 8\)"),
    "flat": ("logits[..., 0].ravel()", r"shape \(\d+,\)"),
    "trailing_one": ("logits[..., :1]", r"shape \(\d, 6, 8, 1\)"),
    "scalar": ("1.0", "float; expected an array"),
    "nothing": ("None", "NoneType; expected an array"),
    "text": ("'high'", "str; expected an array"),
    "int32": ("jnp.zeros(logits.shape[:3], jnp.int32)", "dtype int32"),
    "boolean": ("logits[..., 0] > 0", "dtype bool"),
    "uint8": ("np.zeros(logits.shape[:3], np.uint8)", "dtype uint8"),
    "not_finite": ("jnp.where(jnp.arange(logits.shape[2]) == 3, jnp.nan, logits[..., 0])", "NaN or infinite scores"),
    "infinite": ("jnp.full(logits.shape[:3], jnp.inf)", "NaN or infinite scores"),
}
BAD_PLUGIN = "import jax.numpy as jnp\nimport numpy as np\nfrom jaxanom.method_registry import Method, register\n" + "".join(
    f"register(Method('bad_{kind}', frozenset({{'logits'}}), lambda inputs, options: (lambda logits: {expression})("
    f"jnp.asarray(inputs['logits'])), 'a refused output'))\n" for kind, (expression, _) in BAD_OUTPUTS.items())


def write_module(folder, name, text, monkeypatch):
    """``name``.py holding ``text`` in ``folder``, which goes on sys.path (no bytecode: a rewritten
    module of the same size and second must not be read from a stale .pyc)."""
    folder.mkdir(exist_ok=True)
    (folder / f"{name}.py").write_text(textwrap.dedent(text))
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    sys.modules.pop(name, None)
    return name


def forget(module, *names):
    """As a new process would find it: ``module`` not imported, ``names`` not registered."""
    sys.modules.pop(module, None)
    for name in names:
        method_registry.METHODS.entries.pop(name, None)
        method_registry.METHODS.origins.pop(name, None)


def registering(name, expression="-jnp.max(jnp.asarray(inputs['logits']), axis=-1)", defaults=None):
    return f"""
        import jax.numpy as jnp
        from jaxanom.method_registry import Method, register

        register(Method({name!r}, frozenset({{"logits"}}), lambda inputs, options: {expression},
                        "a test's method", defaults={defaults or {}!r}))
        """


def logits_file(tmp_path, seed=0):
    rng = np.random.default_rng(seed)
    np.save(tmp_path / "logits.npy", rng.normal(size=(B, C, H, W)).astype(np.float32))
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(B, H, W), p=[0.6, 0.3, 0.1])
    np.save(tmp_path / "labels.npy", labels)
    return ["score", "--logits", str(tmp_path / "logits.npy"), "--labels", str(tmp_path / "labels.npy")]


def one_line_error(capsys, argv):
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1, error
    return error


def write_images(folder, count=2, shape=(48, 96)):
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    for index in range(count):
        cv2.imwrite(str(folder / f"f{index}.png"), rng.integers(0, 256, (*shape, 3), dtype=np.uint8))
    return folder


# --- names are names, and nothing is written or removed outside --out ---------------------------

def test_a_method_name_is_never_a_path():
    for name in ("msp", "top2-margin", "energy.t5", "A_1"):
        method_registry.Method(name, frozenset({"logits"}), lambda i, o: 0, "x")
    for name in ("../../victimdir", "/abs/victim", "a/b", "a\\b", ".", "..", "", "a,b", " msp", "m\u00e9thode", None):
        with pytest.raises(ValueError, match="name: expected letters, digits"):
            method_registry.Method(name, frozenset({"logits"}), lambda i, o: 0, "x")
        assert not method_registry.is_name(name)


def test_predict_never_removes_files_outside_out_through_a_plugins_name(
        tiny_run, tmp_path, capsys, monkeypatch, registry_state):  # noqa: F811
    victims = tmp_path / "victimdir"
    victims.mkdir()
    for name in ("a.npy", "b.npy"):
        (victims / name).write_bytes(b"unrelated")
    plugin = write_module(tmp_path / "plugins", "p_victimdir", registering("../../victimdir"), monkeypatch)
    error = one_line_error(capsys, ["predict", str(write_images(tmp_path / "images")), "--run", str(tiny_run),
                                    "--out", str(tmp_path / "p3"), "--overwrite", "--plugin", plugin,
                                    "--methods", "../../victimdir", "--no-progress"])
    assert error.startswith("jaxanom predict: error: --plugin p_victimdir: ") and "'../../victimdir'" in error
    assert sorted(p.name for p in victims.iterdir()) == ["a.npy", "b.npy"]


def test_score_never_replaces_a_file_outside_out_through_a_plugins_name(tmp_path, capsys, monkeypatch,
                                                                       registry_state):  # noqa: F811
    victim = tmp_path / "victim.npy"
    victim.write_bytes(b"unrelated")
    plugin = write_module(tmp_path / "plugins", "p_abs", registering(str(tmp_path / "victim")), monkeypatch)
    error = one_line_error(capsys, [*logits_file(tmp_path), "--plugin", plugin, "--methods", str(tmp_path / "victim"),
                                    "--out", str(tmp_path / "f")])
    assert error.startswith("jaxanom score: error: --plugin p_abs: ")
    assert victim.read_bytes() == b"unrelated"


@pytest.mark.parametrize("command", ["score", "evaluate --maps", "predict"])
def test_every_command_reading_method_names_refuses_a_path(tmp_path, capsys, road_anomaly, command):
    names = "msp,../outside"
    if command == "score":
        argv = [*logits_file(tmp_path), "--methods", names, "--out", str(tmp_path / "o")]
    elif command == "predict":
        argv = ["predict", str(write_images(tmp_path / "images")), "--run", str(tmp_path), "--methods", names,
                "--out", str(tmp_path / "o")]
    else:  # saved maps of the frame, and a method folder beside them that the name would reach
        for method in ("anomaly_p/msp", "outside"):
            folder = tmp_path / "maps" / method / "AnomalyTrack-all"
            folder.mkdir(parents=True)
            with h5py.File(folder / "f.hdf5", "w") as f:
                f.create_dataset("value", data=np.zeros(SIZE, np.float16))
        argv = ["evaluate", "--maps", str(tmp_path / "maps"), "--dataset", "road-anomaly", "--path",
                str(road_anomaly), "--track", "none", "--methods", names, "--out", str(tmp_path / "o")]
    error = one_line_error(capsys, argv)
    assert error.endswith("--methods: expected names of letters, digits, '_', '-', '.' (not '.' or '..'), composed "
                          "with '+', never a path; got '../outside'")
    assert not (tmp_path / "o").exists()


def test_a_symlink_inside_out_does_not_lead_writes_or_removals_outside(tiny_run, tmp_path, capsys):  # noqa: F811
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "msp.npy").write_bytes(b"unrelated")
    out = tmp_path / "f"
    out.mkdir()
    (out / "scores").symlink_to(elsewhere)
    error = one_line_error(capsys, [*logits_file(tmp_path), "--methods", "msp", "--out", str(out), "--overwrite"])
    assert error == f"jaxanom score: error: --out {out}: refusing to write or remove {out}/scores/msp.npy, which lies " \
                    "outside it"
    assert (elsewhere / "msp.npy").read_bytes() == b"unrelated"

    (elsewhere / "f0.npy").write_bytes(b"unrelated")  # predict --overwrite removes the maps of other settings
    out = tmp_path / "p"
    (out / "npy").mkdir(parents=True)
    (out / "npy" / "msp").symlink_to(elsewhere)
    error = one_line_error(capsys, ["predict", str(write_images(tmp_path / "images")), "--run", str(tiny_run),
                                    "--methods", "msp", "--out", str(out), "--overwrite", "--no-progress"])
    assert "refusing to write or remove" in error and "which lies outside it" in error
    assert sorted(p.name for p in elsewhere.iterdir()) == ["f0.npy", "msp.npy"]


# --- what a method returns is checked at one boundary ------------------------------------------------

@pytest.fixture
def bad_plugin(tmp_path, monkeypatch, registry_state):  # noqa: F811
    return write_module(tmp_path / "plugins", "p_bad_outputs", BAD_PLUGIN, monkeypatch)


@pytest.mark.parametrize("kind", list(BAD_OUTPUTS))
def test_score_refuses_each_bad_output_naming_the_method(tmp_path, capsys, bad_plugin, kind):
    for labels in (True, False):
        argv = logits_file(tmp_path)
        argv = argv if labels else argv[:3]
        error = one_line_error(capsys, [*argv, "--plugin", bad_plugin, "--methods", f"msp,bad_{kind}",
                                        "--out", str(tmp_path / f"o{labels}")])
        assert re.search(f"--methods: method 'bad_{kind}' returned .*{BAD_OUTPUTS[kind][1]}", error), error
        assert not (tmp_path / f"o{labels}" / "scores").exists()


@pytest.mark.parametrize("kind", list(BAD_OUTPUTS))
def test_evaluate_and_predict_refuse_each_bad_output_naming_the_method(tmp_path, bad_plugin, kind):
    from jaxanom.app.commands.inputs import load_plugins

    load_plugins([bad_plugin])
    rng = np.random.default_rng(0)
    batches = [{"logits": rng.normal(size=(B, H, W, C)).astype(np.float32),
                "label": rng.choice(np.array([0, 1], np.uint8), size=(B, H, W))}]
    with pytest.raises(InputError, match=f"method 'bad_{kind}' returned .*{BAD_OUTPUTS[kind][1]}"):
        anomaly_results(batches, ("msp", f"bad_{kind}"))

    def network(images):  # a stand-in for a run's network: C logits per pixel of the working size
        return {"logits": np.repeat(images.astype(np.float32), 2, axis=-1)[..., :C]}

    scorer = Scorer(network, PredictSettings(("msp", f"bad_{kind}"), size=(H, W), threads=1))
    with pytest.raises(InputError, match=f"method 'bad_{kind}' returned .*{BAD_OUTPUTS[kind][1]}"):
        predict_images([write_images(tmp_path / "images", 1) / "f0.png"], tmp_path / "out", scorer, progress=False)
    assert not (tmp_path / "out" / "npy" / f"bad_{kind}").exists()  # (msp's map of f0, before it, is written)


def test_predict_refuses_a_bad_output_in_one_line_naming_the_method(tiny_run, tmp_path, capsys,
                                                                     bad_plugin):  # noqa: F811
    error = one_line_error(capsys, ["predict", str(write_images(tmp_path / "images")), "--run", str(tiny_run),
                                    "--plugin", bad_plugin, "--methods", "msp,bad_transposed", "--out",
                                    str(tmp_path / "o"), "--no-progress"])
    assert error == "jaxanom predict: error: --methods: method 'bad_transposed' returned scores of shape (1, 96, 48); " \
                    "expected (B, H, W) = (1, 48, 96), the batch's"


def test_evaluate_refuses_nan_on_non_void_pixels_only(tmp_path, bad_plugin):
    from jaxanom.app.commands.inputs import load_plugins

    load_plugins([bad_plugin])
    rng = np.random.default_rng(0)
    label = rng.choice(np.array([0, 1], np.uint8), size=(1, H, W))
    label[..., 3] = 255  # the NaN column is void: counted nowhere
    batch = {"logits": rng.normal(size=(1, H, W, C)).astype(np.float32), "label": label}
    metrics, _ = anomaly_results([batch], ("bad_not_finite",))
    assert np.isfinite(metrics["bad_not_finite"]["ap"])
    batch["label"] = label.copy()
    batch["label"][0, 0, 3] = 0
    with pytest.raises(InputError, match="method 'bad_not_finite' returned 1 NaN or infinite scores on non-void "
                                         "pixels; expected finite"):
        anomaly_results([batch], ("bad_not_finite",))


# --- methods get read-only inputs ---------------------------------------------------------------------

MUTATING = """
    import jax.numpy as jnp
    from jaxanom.method_registry import Method, register

    def mutate(inputs, options):
        logits = jnp.asarray(inputs["logits"])
        inputs["logits"] = -100 * logits  # what the methods after it would have read
        return -jnp.max(logits, axis=-1)

    register(Method("mutating", frozenset({"logits"}), mutate, "changes the inputs it is handed"))
    """


def test_a_plugin_changing_its_inputs_leaves_the_other_methods_alone(tmp_path, monkeypatch,
                                                                      registry_state):  # noqa: F811
    plugin = write_module(tmp_path / "plugins", "p_mutating", MUTATING, monkeypatch)
    argv = logits_file(tmp_path)
    assert main([*argv, "--methods", "msp,entropy", "--out", str(tmp_path / "alone")]) == 0
    assert main([*argv, "--plugin", plugin, "--methods", "mutating,msp,entropy", "--out", str(tmp_path / "after")]) == 0
    alone, after = (json.loads((tmp_path / f / "metrics.json").read_text())["metrics"] for f in ("alone", "after"))
    for name in ("msp", "entropy"):
        assert after[name]["ap"] == alone[name]["ap"]
        np.testing.assert_array_equal(np.load(tmp_path / "after" / "scores" / f"{name}.npy"),
                                      np.load(tmp_path / "alone" / "scores" / f"{name}.npy"))
    rng = np.random.default_rng(1)  # evaluate's loop, on a network's (immutable) logits
    batch = {"logits": rng.normal(size=(B, H, W, C)).astype(np.float32),
             "label": rng.choice(np.array([0, 1], np.uint8), size=(B, H, W))}
    alone, after = (anomaly_results([batch], names)[0] for names in (("msp",), ("mutating", "msp")))
    assert after["msp"]["ap"] == alone["msp"]["ap"]


def test_a_method_cannot_write_into_the_callers_arrays(registry_state):  # noqa: F811
    logits = np.random.default_rng(0).normal(size=(1, H, W, C)).astype(np.float32)
    stats = (np.zeros(C, np.float32), np.ones(C, np.float32))
    kept = logits.copy()

    def overwrite(inputs, options):
        inputs["logits"][...] = 0
        return inputs["logits"][..., 0]

    def overwrite_stats(inputs, options):
        inputs["stats"][0][:] = 1
        return inputs["logits"][..., 0]

    for function in (overwrite, overwrite_stats):
        method_registry.METHODS.entries.pop(f"writer_{function.__name__}", None)
        method_registry.register(method_registry.Method(f"writer_{function.__name__}", frozenset({"logits", "stats"}),
                                                        function, "x"))
        with pytest.raises(ValueError, match="read-only"):
            method_registry.score(f"writer_{function.__name__}", {"logits": logits, "stats": stats})
    np.testing.assert_array_equal(logits, kept)
    assert logits.flags.writeable and not stats[0].any()  # the caller's own arrays stay as they were


# --- a broken plug-in is one line naming it -----------------------------------------------------------

@pytest.mark.parametrize("case", ["file path", "empty", "duplicate", "built-in name", "raises"])
def test_a_broken_plugin_is_one_line_naming_it(tmp_path, capsys, monkeypatch, registry_state, case):  # noqa: F811
    folder = tmp_path / "plugins"
    write_module(folder, "p_one", registering("twin"), monkeypatch)
    write_module(folder, "p_two", registering("twin", "jnp.max(jnp.asarray(inputs['logits']), axis=-1)"), monkeypatch)
    write_module(folder, "p_msp", registering("msp"), monkeypatch)
    write_module(folder, "p_raises", "import jax\n\nCONSTANT = 1 / 0\n", monkeypatch)
    plugins, expected = {
        "file path": (["./p_one.py"], "--plugin './p_one.py': expected a module's dotted name (e.g. my_scores or "
                                      "package.module), importable from the Python path; not a file (for this "
                                      "file: PYTHONPATH=. and --plugin p_one)"),
        "empty": ([""], "--plugin '': expected a module's dotted name"),
        "duplicate": (["p_one", "p_two"], "--plugin p_two: importing it raised ValueError: method 'twin': already "
                                          "registered by p_one; p_two cannot register another under the same name ("
                                          f"{folder / 'p_two.py'}, line 5)"),
        "built-in name": (["p_msp"], "--plugin p_msp: importing it raised ValueError: method 'msp': already "
                                     "registered by jaxanom.score_methods"),
        "raises": (["p_raises"], "--plugin p_raises: importing it raised ZeroDivisionError: division by zero ("
                                 f"{folder / 'p_raises.py'}, line 3)"),
    }[case]
    error = one_line_error(capsys, [*logits_file(tmp_path), *(f"--plugin={p}" for p in plugins), "--out",
                                    str(tmp_path / "o")])
    assert error.startswith(f"jaxanom score: error: {expected}"), error
    assert not (tmp_path / "o").exists()


# --- predict never resumes maps of other code or options ------------------------------------------------

def run_predict(capsys, images, run, out, plugin, method, *extra):
    code = main(["predict", str(images), "--run", str(run), "--out", str(out), "--plugin", plugin, "--methods",
                 method, "--no-progress", *extra])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def test_predict_recomputes_maps_when_a_plugins_default_option_changes(tiny_run, tmp_path, capsys, monkeypatch,
                                                                       registry_state):  # noqa: F811
    images, out, folder = write_images(tmp_path / "images", 1), tmp_path / "maps", tmp_path / "plugins"
    expression = "-options['temperature'] * jnp.max(jnp.asarray(inputs['logits']), axis=-1)"
    plugin = write_module(folder, "p_temp", registering("temp", expression, {"temperature": 1.0}), monkeypatch)
    assert run_predict(capsys, images, tiny_run, out, plugin, "temp")[0] == 0
    first = np.load(out / "npy" / "temp" / "f0.npy")

    forget(plugin, "temp")  # the next command, in a new process, imports the edited plug-in
    write_module(folder, "p_temp", registering("temp", expression, {"temperature": 4.0}), monkeypatch)
    code, text = run_predict(capsys, images, tiny_run, out, plugin, "temp")
    assert code == 2 and f"--out {out}: holds maps of method 'temp' made by other code" in text
    np.testing.assert_array_equal(np.load(out / "npy" / "temp" / "f0.npy"), first)  # refused, nothing changed
    forget(plugin, "temp")
    code, text = run_predict(capsys, images, tiny_run, out, plugin, "temp", "--overwrite")
    assert code == 0 and "1 frames written, 0 already there" in text
    np.testing.assert_array_equal(np.load(out / "npy" / "temp" / "f0.npy"), 4 * first)  # x4 is exact in float16


def test_predict_never_mixes_frames_of_two_plugins_registering_one_name(tiny_run, tmp_path, capsys, monkeypatch,
                                                                        registry_state):  # noqa: F811
    images, out, folder = tmp_path / "images", tmp_path / "maps", tmp_path / "plugins"
    write_images(images, 2)
    first_frame = tmp_path / "first"
    first_frame.mkdir()
    (first_frame / "f0.png").symlink_to(images / "f0.png")
    plus = write_module(folder, "p_plus", registering("signed", "jnp.max(jnp.asarray(inputs['logits']), axis=-1)"),
                        monkeypatch)
    minus = write_module(folder, "p_minus", registering("signed", "-jnp.max(jnp.asarray(inputs['logits']), axis=-1)"),
                         monkeypatch)
    assert run_predict(capsys, first_frame, tiny_run, out, plus, "signed")[0] == 0
    forget(plus, "signed")
    code, text = run_predict(capsys, images, tiny_run, out, minus, "signed")
    assert code == 2 and "holds maps of method 'signed' made by other code" in text
    assert sorted(p.name for p in (out / "npy" / "signed").iterdir()) == ["f0.npy"]
    forget(minus, "signed")
    code, text = run_predict(capsys, images, tiny_run, out, minus, "signed", "--overwrite")
    assert code == 0 and "2 frames written" in text
    forget(minus, "signed")
    assert "0 frames written, 2 already there" in run_predict(capsys, images, tiny_run, out, minus, "signed")[1]
    record = json.loads((out / "settings.json").read_text())
    assert record["method_code"] == {"signed": {"code": method_registry.implementation("signed"), "options": {}}}


# --- a broken installed plug-in breaks only what needs its names ----------------------------------------

@pytest.fixture
def broken_entry_point(tmp_path, monkeypatch, registry_state):  # noqa: F811
    """An installed distribution (a dist-info on sys.path) with two ``jaxanom.methods`` entry
    points: ``good`` registers ``installed_twin``, ``broken`` fails to import; the registry
    reloads its entry points on next use."""
    site = tmp_path / "site"
    info = site / "jaxanom_test_plugin_dist-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: jaxanom-test-plugin-dist\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[jaxanom.methods]\ngood = jaxanom_test_plugin_good\n"
                                           "broken = jaxanom_test_plugin_broken\n")
    write_module(site, "jaxanom_test_plugin_good", registering("installed_twin"), monkeypatch)
    write_module(site, "jaxanom_test_plugin_broken", "import no_such_dependency_xyz\n", monkeypatch)
    monkeypatch.setattr(method_registry.METHODS, "loaded", False)
    monkeypatch.setattr(method_registry.METHODS, "broken", [])


def test_a_broken_entry_point_breaks_no_help_and_no_command_that_does_not_need_it(tmp_path, capsys,
                                                                                  broken_entry_point):
    for argv in (["--help"], ["train", "--help"], ["convert-weights", "--help"], ["score", "--help"]):
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 0, argv
    assert "installed_twin" in capsys.readouterr().out  # the working entry point's method is listed
    argv = logits_file(tmp_path)
    assert main([*argv, "--methods", "msp,installed_twin", "--out", str(tmp_path / "o")]) == 0
    error = one_line_error(capsys, [*argv, "--methods", "msp,unknown_one", "--out", str(tmp_path / "p")])
    assert error.endswith("got ['msp', 'unknown_one']; the jaxanom.methods entry point broken = "
                          "jaxanom_test_plugin_broken (jaxanom-test-plugin-dist) failed to load (ModuleNotFoundError: "
                          "No module named 'no_such_dependency_xyz') (fix or uninstall it, or set "
                          "JAXANOM_DISABLE_ENTRY_POINTS=1)"), error


def test_entry_points_can_be_switched_off(tmp_path, capsys, monkeypatch, broken_entry_point):
    monkeypatch.setenv("JAXANOM_DISABLE_ENTRY_POINTS", "1")
    method_registry.METHODS.entries.pop("installed_twin", None)
    assert "installed_twin" not in method_registry.names()
    error = one_line_error(capsys, [*logits_file(tmp_path), "--methods", "installed_twin", "--out", str(tmp_path / "o")])
    assert "got ['installed_twin']" in error and "entry point" not in error


def test_a_method_named_twice_is_one_line_before_any_output(tmp_path, capsys):
    """Two writers of one scores/<method>.npy: refused before the folder is made."""
    error = one_line_error(capsys, [*logits_file(tmp_path), "--methods", "msp,entropy,msp", "--out",
                                    str(tmp_path / "o")])
    assert error.endswith("--methods: expected each method once (one output each), got 'msp' twice")
    assert not (tmp_path / "o").exists()
