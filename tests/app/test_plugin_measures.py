"""Evaluators and evaluation protocols are plug-ins like methods: an outside module registers an
evaluator (``score --evaluators``) and a protocol (``evaluate --protocol``, ``fit-stats --protocol``),
loaded by ``--plugin`` or an entry point; a name no registry knows is one line naming the flag, the
known names and a broken entry point that might have provided it; ``--help`` lists jaxanom's own
protocols and evaluators whatever is installed."""
import json
import sys
import textwrap

import cv2
import numpy as np
import pytest
from PIL import Image

from jaxanom import registry
from jaxanom.cli import main
from converted_run import tiny_run  # noqa: F401  (the module fixture: a tiny converted run)
from test_method_registry import road_anomaly  # noqa: F401  (a Road Anomaly folder of one frame at SIZE)

MODULE = "jaxanom_test_measures"
MEASURES = '''
    """An extension author's module: an evaluator and a protocol."""
    import dataclasses

    import numpy as np

    from jaxanom.metrics.evaluator import NamedEvaluator, register
    from jaxanom.protocols import Protocol, register as register_protocol


    @dataclasses.dataclass(frozen=True)
    class ScoreGap:  # mean score of anomalous pixels minus that of normal ones
        method: str

        def init(self):
            return np.zeros(4)

        def update(self, state, batch):
            scores, label = np.asarray(batch["scores"][self.method], np.float64), np.asarray(batch["label"])
            return state + [scores[label == 1].sum(), (label == 1).sum(), scores[label == 0].sum(), (label == 0).sum()]

        def merge(self, a, b):
            return a + b

        def finalize(self, state):
            return {"gap": state[0] / state[1] - state[2] / state[3], "pixels": state[[1, 3]].astype(int)}


    register(NamedEvaluator("score_gap", ScoreGap, "mean anomalous minus mean normal score"))
    register_protocol(Protocol("small", "frames at 32x64, interpolated FPR95", size=(32, 64), fpr_convention="interp"))
'''


@pytest.fixture
def measures(tmp_path, monkeypatch):
    """The module on sys.path; every registry restored after the test, the module forgotten."""
    site = tmp_path / "site"
    site.mkdir()
    (site / f"{MODULE}.py").write_text(textwrap.dedent(MEASURES))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    for kind in registry._ALL:
        kind.names()
        for attribute in ("entries", "origins", "broken"):
            monkeypatch.setattr(kind, attribute, type(getattr(kind, attribute))(getattr(kind, attribute)))
    forget()
    yield site
    forget()


def forget():
    """As a new process finds them: the test's modules not imported, their names not registered, the
    entry points not read."""
    for module in [m for m in sys.modules if m.startswith(MODULE)]:
        del sys.modules[module]
    for kind in registry._ALL:
        kind.loaded = False
        for name in [name for name, origin in kind.origins.items() if origin.startswith(MODULE)]:
            del kind.entries[name], kind.origins[name]


def command(capsys, *argv):
    """``jaxanom argv`` as a new process runs it: its exit status and output."""
    forget()
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def one_line_error(capsys, *argv):
    code, text = command(capsys, *argv)
    assert code == 2 and len(text.strip().splitlines()) == 1, text
    return text.strip()


def test_an_outside_evaluator_runs_by_name_in_score(tmp_path, capsys, measures):
    rng = np.random.default_rng(0)
    np.save(tmp_path / "logits.npy", rng.normal(size=(3, 5, 12, 16)).astype(np.float32))
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(3, 12, 16), p=[0.6, 0.3, 0.1])
    np.save(tmp_path / "labels.npy", labels)
    argv = ("score", "--logits", tmp_path / "logits.npy", "--labels", tmp_path / "labels.npy", "--methods",
            "msp,energy", "--evaluators", "score_gap,pixel")
    error = one_line_error(capsys, *argv, "--out", tmp_path / "no")
    assert error.startswith("jaxanom score: error: --evaluators: expected names from pixel, smiyc_pixels, got "
                            "'score_gap' (a plug-in's evaluator: load its module, e.g. with --plugin MODULE)"), error
    assert not (tmp_path / "no").exists()

    code, text = command(capsys, *argv, "--plugin", MODULE, "--out", tmp_path / "o")
    assert code == 0, text
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())["metrics"]
    for method in ("msp", "energy"):
        scores = np.load(tmp_path / "o" / "scores" / f"{method}.npy").astype(np.float64)
        gap = scores[labels == 1].mean() - scores[labels == 0].mean()
        evaluated = metrics[method]["evaluators"]
        assert evaluated["score_gap"]["gap"] == pytest.approx(gap, rel=1e-12)
        assert evaluated["score_gap"]["pixels"] == [int((labels == 1).sum()), int((labels == 0).sum())]
        assert evaluated["pixel"]["ap"] == metrics[method]["ap"]  # the built-in by name: the same pooled metrics
        assert f"{method} score_gap: {{'gap': " in text

    error = one_line_error(capsys, "score", "--logits", tmp_path / "logits.npy", "--evaluators", "pixel", "--out",
                           tmp_path / "p")
    assert error.endswith("--evaluators: the evaluators compare scores with labels; give --labels"), error


def anomaly_track_and_maps(tmp_path, methods=("a", "b")):
    """A SegmentMeIfYouCan RoadAnomaly21 folder of three 12x16 frames (labels 0 / 1 / 255) and, in
    ``tmp_path / "pred"``, random float16 maps of ``methods`` as ``predict --format smiyc`` writes
    them (ties included); returns the folder, the labels and ``{method: maps}``."""
    import h5py

    rng = np.random.default_rng(3)
    root = tmp_path / "track"
    for folder in ("images", "labels_masks"):
        (root / folder).mkdir(parents=True)
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(3, 12, 16), p=[0.6, 0.3, 0.1])
    maps = {method: rng.normal(size=labels.shape).round(1).astype(np.float16) for method in methods}
    for index, label in enumerate(labels):
        cv2.imwrite(str(root / "images" / f"f{index}.png"), np.zeros((*label.shape, 3), np.uint8))
        cv2.imwrite(str(root / "labels_masks" / f"f{index}_labels_semantic.png"), label)
        for method, values in maps.items():
            folder = tmp_path / "pred" / "anomaly_p" / method / "AnomalyTrack-all"
            folder.mkdir(parents=True, exist_ok=True)
            with h5py.File(folder / f"f{index}.hdf5", "w") as f:
                f.create_dataset("value", data=values[index])
    return root, labels, maps


def test_an_outside_evaluator_runs_by_name_in_evaluate(tmp_path, capsys, measures):
    """``evaluate --evaluators``: the module's evaluator against NumPy on the same float16 maps and
    labels, ``pixel`` by name equal to the default metrics, and every other number of metrics.json
    as without ``--evaluators``."""
    root, labels, maps = anomaly_track_and_maps(tmp_path)
    argv = ("evaluate", "--maps", tmp_path / "pred", "--dataset", "smiyc", "--track", "anomaly", "--path", root)
    error = one_line_error(capsys, *argv, "--evaluators", "score_gap,pixel", "--out", tmp_path / "no")
    assert error.startswith("jaxanom evaluate: error: --evaluators: expected names from pixel, smiyc_pixels, got "
                            "'score_gap' (a plug-in's evaluator: load its module, e.g. with --plugin MODULE)"), error
    assert not (tmp_path / "no").exists()

    code, text = command(capsys, *argv, "--evaluators", "score_gap,pixel", "--plugin", MODULE,
                         "--out", tmp_path / "named")
    assert code == 0, text
    named = json.loads((tmp_path / "named" / "metrics.json").read_text())
    for method, values in maps.items():
        scores = values.astype(np.float64)
        evaluated = named["metrics"][method].pop("evaluators")
        assert set(evaluated) == {"score_gap", "pixel"}
        assert evaluated["score_gap"]["gap"] == pytest.approx(scores[labels == 1].mean() - scores[labels == 0].mean(),
                                                              rel=1e-12)
        assert evaluated["score_gap"]["pixels"] == [int((labels == 1).sum()), int((labels == 0).sum())]
        for key in ("ap", "auroc", "fpr_at_tpr", "best_f1", "best_f1_threshold"):  # the default conventions
            assert evaluated["pixel"][key] == named["metrics"][method][key], (method, key)
        assert f"{method} score_gap: {{'gap': " in text

    code, text = command(capsys, *argv, "--out", tmp_path / "plain")
    assert code == 0, text
    assert json.loads((tmp_path / "plain" / "metrics.json").read_text()) == named  # less "evaluators": the same


def test_an_outside_protocol_runs_by_name_in_evaluate(tmp_path, capsys, measures, tiny_run,  # noqa: F811
                                                     road_anomaly):  # noqa: F811
    """The module's protocol resizes the frame to 32x64 and interpolates FPR95: the same numbers as
    the native protocol on the frame resized by PIL beforehand with the interpolated FPR95; the
    network's scores also through ``--evaluators pixel`` (its own FPR95 convention, first)."""
    argv = ("evaluate", "--run", tiny_run, "--dataset", "road-anomaly", "--methods", "msp,max_logit")
    error = one_line_error(capsys, *argv, "--path", road_anomaly, "--protocol", "small", "--out", tmp_path / "no")
    assert error == ("jaxanom evaluate: error: --protocol: expected one of native, erfnet-community, got 'small' (a "
                     "plug-in's protocol: load its module, e.g. with --plugin MODULE)"), error
    assert not (tmp_path / "no").exists()
    error = one_line_error(capsys, "fit-stats", "--run", tiny_run, "--protocol", "small", "--out", tmp_path / "s.npz")
    assert error.startswith("jaxanom fit-stats: error: --protocol: expected one of native, erfnet-community, got "
                            "'small'"), error

    code, text = command(capsys, *argv, "--path", road_anomaly, "--protocol", "small", "--plugin", MODULE,
                         "--evaluators", "pixel", "--out", tmp_path / "small")
    assert code == 0, text
    small = json.loads((tmp_path / "small" / "metrics.json").read_text())
    assert small["protocol"] == "small"

    resized = tmp_path / "resized"  # the frame as the protocol reads it, by PIL
    (resized / "frames" / "f.labels").mkdir(parents=True)
    (resized / "frame_list.json").write_text('["f.png"]')
    frames = road_anomaly / "frames"
    image = Image.fromarray(cv2.imread(str(frames / "f.png"))[..., ::-1]).resize((64, 32), Image.BILINEAR)
    cv2.imwrite(str(resized / "frames" / "f.png"), np.asarray(image)[..., ::-1])
    label = Image.open(frames / "f.labels" / "labels_semantic.png").resize((64, 32), Image.NEAREST)
    label.save(resized / "frames" / "f.labels" / "labels_semantic.png")
    code, text = command(capsys, *argv, "--path", resized, "--fpr-convention", "interp", "--out", tmp_path / "native")
    assert code == 0, text
    native = json.loads((tmp_path / "native" / "metrics.json").read_text())
    for method in ("msp", "max_logit"):
        for key in ("ap", "auroc", "fpr_at_tpr"):
            assert small["metrics"][method][key] == native["metrics"][method][key], (method, key)
        pixel = small["metrics"][method]["evaluators"]["pixel"]
        assert (pixel["ap"], pixel["auroc"]) == (native["metrics"][method]["ap"], native["metrics"][method]["auroc"])
        assert pixel["fpr_at_tpr"] == native["metrics"][method]["fpr_conventions"]["first"]


@pytest.fixture
def installed(measures, monkeypatch):
    """An installed distribution with entry points of both groups: ``good`` registers the module's
    evaluator and protocol, ``broken`` fails to import."""
    info = measures / "jaxanom_test_measures_dist-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: jaxanom-test-measures\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("".join(f"[jaxanom.{group}]\ngood = {MODULE}\nbroken = {MODULE}_broken\n"
                                                   for group in ("evaluators", "protocols")))
    (measures / f"{MODULE}_broken.py").write_text("import no_such_dependency_xyz\n")
    return measures


def test_a_broken_entry_point_breaks_no_help_and_is_named_by_an_unknown_name(tmp_path, capsys, installed):
    from jaxanom.metrics.evaluator import evaluator_names, get_evaluator
    from jaxanom.protocols import get_protocol, protocol_names

    for argv in (["--help"], ["evaluate", "--help"], ["fit-stats", "--help"], ["score", "--help"]):
        forget()
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 0, argv
    shown = " ".join(capsys.readouterr().out.split())
    assert "--protocol NAME how frames become counted pixels (with --run): native:" in shown
    assert "erfnet-community: 512x1024 PIL resize" in shown and "smiyc_pixels: the official" in shown

    forget()  # the working entry point's names are found without --plugin
    assert "small" in protocol_names() and get_protocol("small").size == (32, 64)
    assert "score_gap" in evaluator_names() and get_evaluator("score_gap").make("msp").method == "msp"
    note = ("failed to load (ModuleNotFoundError: No module named 'no_such_dependency_xyz') (fix or uninstall it, "
            "or set JAXANOM_DISABLE_ENTRY_POINTS=1)")
    (tmp_path / "maps").mkdir()
    error = one_line_error(capsys, "evaluate", "--maps", tmp_path / "maps", "--dataset", "road-anomaly", "--path",
                           tmp_path, "--protocol", "absent", "--out", tmp_path / "o")
    assert "got 'absent'" in error and error.endswith(
        f"the jaxanom.protocols entry point broken = {MODULE}_broken (jaxanom-test-measures) {note}"), error
    error = one_line_error(capsys, "score", "--logits", tmp_path / "l.npy", "--evaluators", "absent", "--out",
                           tmp_path / "o")
    assert "got 'absent'" in error and error.endswith(
        f"the jaxanom.evaluators entry point broken = {MODULE}_broken (jaxanom-test-measures) {note}"), error


def test_evaluators_and_protocols_follow_the_registry_rules(measures):
    from jaxanom.metrics.evaluator import NamedEvaluator, PixelAnomaly, register
    from jaxanom.protocols import Protocol, register as register_protocol

    assert {kind.group for kind in registry._ALL} >= {"jaxanom.evaluators", "jaxanom.protocols"}
    with pytest.raises(ValueError, match=r"^protocol 'native': already registered by jaxanom.protocols; "):
        register_protocol(Protocol("native", "another"))
    with pytest.raises(ValueError, match=r"^evaluator name: expected letters, digits, '_', '-', '.' \(not '.' or "
                                         r"'..'\), got '../gap'$"):
        register(NamedEvaluator("../gap", PixelAnomaly, "a path"))


def test_a_value_a_named_evaluator_refuses_is_an_input_error_naming_it():
    """``smiyc_pixels`` by name, under the exact convention (whose checks let it through), meets a
    score beyond float16: one InputError naming the flag, the evaluator, the method and the frame."""
    from jaxanom.app.evaluate import anomaly_results
    from jaxanom.errors import InputError

    label = np.zeros((1, 4, 5), np.uint8)
    label[0, :2] = 1
    maps = np.linspace(0, 1e5, 20, dtype=np.float32).reshape(1, 4, 5)
    with pytest.raises(InputError, match=r"^evaluators: smiyc_pixels refused m's scores of frame f0: scores: expected "
                                         r"finite values within float16's range"):
        anomaly_results([{"maps": {"m": maps}, "label": label, "name": ["f0"]}], ["m"], evaluators=("smiyc_pixels",))
