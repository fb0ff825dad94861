"""SML statistics of a network with a void output under a protocol that drops it: ``fit-stats
--protocol`` fits them on the outputs the methods see and records it; ``evaluate`` refuses
statistics of other outputs in one line before the network runs.

A tiny 20-output network (19 trainIds and a void output); the protocol's size is made small here
(the class selection, not the size, is under test) to keep it cheap."""
import dataclasses
import json

import jax
import numpy as np
import pytest
from PIL import Image

from converted_run import write_tiny_cityscapes, write_tiny_run
from jaxanom import protocols
from jaxanom.cli import main
from jaxanom.sml import load_stats, load_stats_info

SIZE = (64, 128)


@pytest.fixture(scope="module")
def run20(tmp_path_factory):
    return write_tiny_run(tmp_path_factory.mktemp("tiny20") / "run", 20)


@pytest.fixture(autouse=True)
def small_protocol(monkeypatch):
    protocol = dataclasses.replace(protocols.PROTOCOLS.entries["erfnet-community"], size=SIZE)
    monkeypatch.setitem(protocols.PROTOCOLS.entries, "erfnet-community", protocol)


@pytest.fixture(scope="module")
def stats_files(run20, tmp_path_factory):
    """Statistics of 2 Cityscapes-layout frames: as the protocol scores them, and of every output."""
    folder = tmp_path_factory.mktemp("stats")
    frames = write_tiny_cityscapes(folder / "cityscapes", [SIZE, SIZE])
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(protocols.PROTOCOLS.entries, "erfnet-community",
                      dataclasses.replace(protocols.PROTOCOLS.entries["erfnet-community"], size=SIZE))
        for name, extra in (("dropped", ["--protocol", "erfnet-community"]), ("all", ["--size", "64x128"])):
            assert main(["fit-stats", "--run", str(run20), "--frames", "2", "--policy", "none", "--missing", "pooled",
                         "--cityscapes", str(frames), "--out", str(folder / f"{name}.npz"), *extra]) == 0
    return folder / "dropped.npz", folder / "all.npz"


@pytest.fixture(scope="module")
def smiyc(tmp_path_factory):
    """Two 96x160 frames in RoadAnomaly21's layout, an anomaly square in each, void at the bottom."""
    folder = tmp_path_factory.mktemp("smiyc")
    rng = np.random.default_rng(0)
    for sub in ("images", "labels_masks"):
        (folder / sub).mkdir()
    for index in range(2):
        label = np.zeros((96, 160), np.uint8)
        label[30 + 10 * index:60, 40:90], label[85:] = 1, 255
        Image.fromarray(rng.integers(0, 256, (96, 160, 3), dtype=np.uint8)).save(folder / "images" / f"{index}.png")
        Image.fromarray(label).save(folder / "labels_masks" / f"{index}_labels_semantic.png")
    return folder


def evaluate(run, out, stats, path, protocol="erfnet-community", extra=()):
    return main(["evaluate", "--run", str(run), "--dataset", "smiyc", "--track", "anomaly", "--path", str(path),
                 "--protocol", protocol, "--methods", "sml,sml_post", "--stats", str(stats), "--out", str(out),
                 *extra])


def test_fit_stats_drops_the_void_output_as_the_protocol_does(run20, stats_files):
    from jaxanom.app.experiment import load_variables
    from jaxanom.data.transforms import normalize
    from jaxanom.models import build_model

    mean, std, counts = load_stats(stats_files[0])
    assert len(mean) == 19 and len(load_stats(stats_files[1])[0]) == 20
    assert load_stats_info(stats_files[0])["channels"] == {"protocol": "erfnet-community", "network_outputs": 20,
                                                          "void_dropped": True}
    assert load_stats_info(stats_files[1])["channels"]["void_dropped"] is False
    # reference: the frames resized by PIL, the logits without channel 19, per-class moments in NumPy
    experiment, variables = load_variables(run20)
    files = sorted((stats_files[0].parent / "cityscapes").rglob("*_leftImg8bit.png"))
    images = np.stack([np.asarray(Image.open(path).convert("RGB").resize(SIZE[::-1], Image.BILINEAR))
                       for path in files])
    model = build_model("deeplabv3plus_tiny", num_classes=20, attention=None, output_stride=16)
    logits = np.asarray(jax.jit(lambda x: model.apply(variables, normalize(x), train=False)["logits"])(images),
                        np.float64)[..., :19].reshape(-1, 19)
    predicted, value = logits.argmax(-1), logits.max(-1)
    np.testing.assert_array_equal(counts, np.bincount(predicted, minlength=19))
    for c in np.flatnonzero(counts >= 2):
        np.testing.assert_allclose([mean[c], std[c]], [value[predicted == c].mean(), value[predicted == c].std(ddof=1)],
                                   rtol=1e-4)


def test_evaluate_sml_with_the_protocol_on_a_20_output_network(run20, stats_files, smiyc, tmp_path):
    assert evaluate(run20, tmp_path / "out", stats_files[0], smiyc, extra=["--pictures", "1"]) == 0
    record = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert set(record["metrics"]) == {"sml", "sml_post"} and record["protocol"] == "erfnet-community"
    assert record["sml_statistics"]["channels"]["void_dropped"] is True
    assert (tmp_path / "out" / "frame_0.png").is_file()


@pytest.mark.parametrize("which, protocol, advice", [
    (1, "erfnet-community", "the methods see 19 (the network's 20 outputs less the void output, which protocol "
                            "erfnet-community drops); fit them with fit-stats --protocol erfnet-community"),
    (0, "native", "fitted without the void output (fit-stats --protocol erfnet-community), the methods see all 20 "
                  "outputs here; use them with evaluate --protocol erfnet-community")])
def test_statistics_of_other_outputs_are_refused_before_the_network_runs(run20, stats_files, smiyc, tmp_path, capsys,
                                                                        monkeypatch, which, protocol, advice):
    import jaxanom.app.evaluate

    monkeypatch.setattr(jaxanom.app.evaluate, "predictor", lambda *a: pytest.fail("the network was built"))
    assert evaluate(run20, tmp_path / "out", stats_files[which], smiyc, protocol) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and error.startswith("jaxanom evaluate: error: --stats ") and advice in error
    assert not (tmp_path / "out").exists()


def test_fit_stats_refuses_a_size_beside_a_protocol_that_has_one(run20, tmp_path, capsys):
    assert main(["fit-stats", "--run", str(run20), "--protocol", "erfnet-community", "--size", "32x64",
                 "--out", str(tmp_path / "s.npz")]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "--size and --protocol erfnet-community" in error
    assert not list(tmp_path.iterdir())


def test_predict_refuses_statistics_without_the_void_output(run20, stats_files, smiyc, tmp_path, capsys):
    """``predict`` scores every output: statistics fitted without the void one are refused, with the way out."""
    assert main(["predict", str(smiyc / "images" / "0.png"), "--run", str(run20), "--methods", "sml",
                 "--stats", str(stats_files[0]), "--out", str(tmp_path / "p")]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "--stats" in error
    assert "use them with evaluate --protocol erfnet-community" in error


def test_the_protocol_evaluates_synthetic_frames_which_carry_depth(run20, tmp_path):
    """Synthetic frames carry a depth map: the protocol leaves it out instead of failing mid-run."""
    assert main(["evaluate", "--run", str(run20), "--dataset", "synthetic", "--path", "anomaly", "--frames", "2",
                 "--protocol", "erfnet-community", "--methods", "msp", "--out", str(tmp_path / "out")]) == 0
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["protocol"] == "erfnet-community"
