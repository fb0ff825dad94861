"""Broken files, races, permissions, streaming and one-line errors."""
import json
import os
import stat

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom import sml
from jaxanom.app import outputs
from jaxanom.errors import InputError
from jaxanom.app.streamed_array import StreamedArray
from jaxanom.cli import main
from jaxanom.data.image_io import read_label, read_rgb
from jaxanom.app.experiment import Experiment, frames
from jaxanom import io as atomic_io
from jaxanom.metrics import anomaly_metrics


def _one_line_error(capsys, code, *fragments):
    error = capsys.readouterr().err.strip()
    assert code == 2 and len(error.splitlines()) == 1 and "Traceback" not in error, error
    for fragment in fragments:
        assert fragment in error, error
    return error


def _encoded(ext):
    image = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (48, 64, 3), np.uint8), (9, 9), 3)
    return cv2.imencode(ext, image if ext == ".jpg" else image[..., 0])[1].tobytes()


@pytest.mark.parametrize("ext, reader", [(".jpg", read_rgb), (".png", read_label)])
def test_truncated_image_is_an_error_naming_the_file(tmp_path, ext, reader):
    data = _encoded(ext)
    whole = tmp_path / f"whole{ext}"
    whole.write_bytes(data)
    assert reader(whole).shape[:2] == (48, 64)
    for cut in (len(data) // 2, len(data) - 2):
        broken = tmp_path / f"cut{cut}{ext}"
        broken.write_bytes(data[:cut])
        with pytest.raises(ValueError, match=f"cannot decode .*{broken.name}"):
            reader(broken)


def test_two_claims_on_one_output_folder(tmp_path):
    out = tmp_path / "out"
    try:
        outputs.out_folder(str(out), overwrite=False)
        with pytest.raises(InputError, match="another jaxanom command is writing there"):
            outputs.out_folder(str(out), overwrite=True)
        assert (out / outputs.CLAIM).is_file()
    finally:
        outputs.release_claims()
    assert not (out / outputs.CLAIM).exists()
    outputs.out_folder(str(out), overwrite=False)  # released: the (still empty) folder can be claimed again
    outputs.release_claims()


def test_second_command_into_a_claimed_folder_fails_clearly(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / outputs.CLAIM).write_text(f"{os.getppid()}\n")  # a first command, still running
    np.save(tmp_path / "l.npy", np.zeros((1, 3, 4, 5), np.float32))
    code = main(["score", "--logits", str(tmp_path / "l.npy"), "--methods", "msp", "--out", str(out)])
    _one_line_error(capsys, code, "another jaxanom command")
    assert sorted(p.name for p in out.iterdir()) == [outputs.CLAIM]  # nothing written, its claim left alone


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_atomic_files_honour_the_umask(tmp_path, umask):
    old = os.umask(umask)
    try:
        atomic_io.write_bytes_atomic(tmp_path / "a.bin", b"x")
        with atomic_io.NpyWriter(tmp_path / "b.npy", (1, 2), np.float32) as writer:
            writer.write(np.ones(2))
    finally:
        os.umask(old)
    for name in ("a.bin", "b.npy"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o666 & ~umask
    np.testing.assert_array_equal(np.load(tmp_path / "b.npy"), np.ones((1, 2), np.float32))


def test_npy_writer_leaves_nothing_when_interrupted(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_io.NpyWriter(tmp_path / "s.npy", (3, 2), np.float32) as writer:
            writer.write(np.ones(2))
            raise RuntimeError("stopped")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kind", ["npy", "npz", "npz_compressed", "npz_fortran"])
def test_streamed_array_reads_image_by_image(tmp_path, kind):
    array = np.random.default_rng(1).normal(size=(3, 2, 4, 5)).astype(np.float16)
    path = tmp_path / f"a.{kind[:3]}"
    if kind == "npy":
        np.save(path, array)
    else:
        save = np.savez_compressed if kind == "npz_compressed" else np.savez
        save(path, logits=np.asfortranarray(array) if kind == "npz_fortran" else array)
    streamed = StreamedArray(str(path), "logits")
    assert streamed.shape == array.shape and streamed.dtype == array.dtype
    np.testing.assert_array_equal(np.stack(list(streamed)), array)


def test_score_streams_the_input_and_its_scores(tmp_path):
    rng = np.random.default_rng(2)
    logits = rng.normal(size=(4, 3, 6, 7)).astype(np.float32)
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(4, 6, 7))
    np.save(tmp_path / "l.npy", logits)
    np.savez_compressed(tmp_path / "y.npz", labels=labels)
    out = tmp_path / "out"
    assert main(["score", "--logits", str(tmp_path / "l.npy"), "--labels", str(tmp_path / "y.npz"),
                 "--methods", "max_logit,energy", "--out", str(out)]) == 0
    max_logit = np.load(out / "scores" / "max_logit.npy", mmap_mode="r")
    np.testing.assert_array_equal(max_logit, -logits.max(axis=1))
    expected = anomaly_metrics(-logits.max(axis=1), labels)
    assert json.loads((out / "metrics.json").read_text())["metrics"]["max_logit"]["ap"] == pytest.approx(expected["ap"])
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "scores"]  # claim released


def test_score_refuses_nan_at_any_size_with_one_line(tmp_path, capsys):
    logits = np.zeros((2, 3, 70, 80), np.float32)  # 16800 values per image, above 4096
    logits[1, 2, 69, 5] = np.nan
    np.save(tmp_path / "l.npy", logits)
    out = tmp_path / "o"
    code = main(["score", "--logits", str(tmp_path / "l.npy"), "--methods", "max_logit", "--out", str(out)])
    _one_line_error(capsys, code, "image 1: logits must be finite, got 1 NaN")
    assert not (out / "scores" / "max_logit.npy").exists()


@pytest.mark.parametrize("layout, shape", [("NCHW", (1, 12, 5, 40)), ("NHWC", (1, 5, 40, 12))])
def test_score_refuses_a_class_axis_longer_than_a_spatial_one(tmp_path, capsys, layout, shape):
    np.save(tmp_path / "l.npy", np.zeros(shape, np.float32))
    args = ["score", "--logits", str(tmp_path / "l.npy"), "--layout", layout, "--methods", "msp"]
    _one_line_error(capsys, main([*args, "--out", str(tmp_path / "a")]), "--layout", "--any-layout")
    assert main([*args, "--any-layout", "--out", str(tmp_path / "b")]) == 0


def _broken_inputs(tmp_path):
    logits = np.zeros((1, 3, 4, 5), np.float32)
    np.save(tmp_path / "good.npy", logits)
    (tmp_path / "empty.npy").write_bytes(b"")
    np.savez(tmp_path / "whole.npz", logits=logits)
    data = (tmp_path / "whole.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 2])
    (tmp_path / "cut_member.npz").write_bytes(data[:len(data) - 40])
    np.save(tmp_path / "stats.npy", np.ones(3, np.float32))
    np.savez(tmp_path / "strings.npz", mean=np.array(["a", "b", "c"]), std=np.ones(3), counts=np.ones(3, int))
    np.savez(tmp_path / "mismatch.npz", mean=np.zeros(3), std=np.ones(2), counts=np.ones(3, int))
    np.savez(tmp_path / "negative.npz", mean=np.zeros(3), std=-np.ones(3), counts=np.ones(3, int))
    np.savez(tmp_path / "matrix.npz", mean=np.zeros((3, 1)), std=np.ones((3, 1)), counts=np.ones((3, 1), int))


@pytest.mark.parametrize("logits, stats, message", [
    ("empty.npy", None, "empty.npy"), ("cut.npz", None, "cut.npz"), ("cut_member.npz", None, "cut_member.npz"),
    ("good.npy", "stats.npy", "stats.npy"), ("good.npy", "strings.npz", "mean must be floating"),
    ("good.npy", "mismatch.npz", "one shape (C,)"), ("good.npy", "negative.npz", "std must be finite and > 0"),
    ("good.npy", "matrix.npz", "one shape (C,)")])
def test_broken_input_files_are_one_line(tmp_path, capsys, logits, stats, message):
    _broken_inputs(tmp_path)
    args = ["score", "--logits", str(tmp_path / logits), "--out", str(tmp_path / "o")]
    args += ["--methods", "msp"] if stats is None else ["--stats", str(tmp_path / stats), "--methods", "sml"]
    _one_line_error(capsys, main(args), message)


def test_load_stats_checks_what_it_reads(tmp_path):
    _broken_inputs(tmp_path)
    for name, message in [("mismatch.npz", "one shape"), ("negative.npz", "std must"), ("strings.npz", "floating"),
                          ("stats.npy", "expected an .npz file")]:
        with pytest.raises(ValueError, match=message):
            sml.load_stats(tmp_path / name)


def test_output_folder_that_cannot_be_created_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    np.save(tmp_path / "l.npy", np.zeros((1, 3, 4, 5), np.float32))
    code = main(["score", "--logits", str(tmp_path / "l.npy"), "--methods", "msp",
                 "--out", str(tmp_path / "file" / "sub")])  # a folder under a file: the OS refuses
    _one_line_error(capsys, code, "cannot create")


def test_train_config_errors_are_one_line(tmp_path, capsys):
    for text, message in [("experiment = (", "SyntaxError (line 1)"), ("import sys\nsys.exit(0)\n", "sys.exit(0)"),
                          ("raise RuntimeError('no data')\n", "RuntimeError: no data")]:
        config = tmp_path / "c.py"
        config.write_text(text)
        code = main(["train", "--config", str(config), "--out", str(tmp_path / "run"), "--no-progress"])
        _one_line_error(capsys, code, message)


def test_resume_of_a_damaged_experiment_json_is_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    for text in ("{}", "{not json", '{"model": 1}'):
        (run / "experiment.json").write_text(text)
        _one_line_error(capsys, main(["train", "--resume", "--out", str(run), "--no-progress"]), "experiment.json")


def test_failed_train_does_not_block_its_retry(tmp_path, capsys):
    run = tmp_path / "run"
    code = main(["train", "--data", "cityscapes", "--data-root", str(tmp_path / "nowhere"), "--out", str(run),
                 "--no-progress"])
    _one_line_error(capsys, code, "nowhere")
    assert not run.exists()  # nothing written, the folder it made removed: a retry may start
    outputs.out_folder(str(run), overwrite=False)
    outputs.release_claims()


def test_fit_stats_refuses_zero_frames_and_a_folder_as_output(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["fit-stats", "--run", str(tmp_path), "--frames", "0", "--out", str(tmp_path / "s.npz")])
    assert stop.value.code == 2 and ">= 1" in capsys.readouterr().err
    code = main(["fit-stats", "--run", str(tmp_path), "--out", str(tmp_path), "--overwrite"])
    _one_line_error(capsys, code, "is a folder")


def test_frames_are_bounded_by_the_training_set():
    experiment = Experiment(train_frames=8, batch_size=4)
    assert len(frames(experiment, "train", 10**9)) == 8
    assert len(frames(experiment, "train", 3)) == 3
    assert len(frames(experiment, "val", 20)) == 20
    with pytest.raises(ValueError, match="num_frames"):
        frames(experiment, "train", 0)


def test_int8_labels_with_minus_one_are_not_void():
    scores = np.arange(4, dtype=np.float32)
    with pytest.raises(ValueError, match="labels: expected values"):
        anomaly_metrics(scores, np.array([0, 1, -1, 1], np.int8))
    np.testing.assert_equal(anomaly_metrics(scores, np.array([0, 1, 0, 1], np.int8))["auroc"], 0.75)


def test_nan_statistics_are_blamed_on_nan_input():
    stats = sml.stats_update(sml.stats_init(2), np.ones((3, 3, 2), np.float32) * np.arange(2))
    poisoned = sml.stats_merge(stats, sml.ClassStats(*(jnp.full(2, jnp.nan) for _ in range(3))))
    with pytest.raises(ValueError, match="NaN or Inf logits were counted"):
        sml.stats_finalize(poisoned, missing="pooled")
    logits = np.ones((80, 80, 2), np.float32)
    logits[5, 5, 0] = np.nan
    with pytest.raises(ValueError, match="logits must be finite"):
        sml.fit_stats([logits])


def test_demo_frame_pictures_have_panel_titles(tmp_path, monkeypatch):
    from jaxanom import viz
    from jaxanom.app.reports import write_pictures
    from jaxanom.data import SyntheticScenes

    drawn = []
    real = viz.write_panels
    monkeypatch.setattr(viz, "write_panels", lambda path, panels, **kw: (drawn.append(panels), real(path, panels, **kw)))
    source = SyntheticScenes("anomaly", 1, 0, height=32, width=48)
    logits = np.random.default_rng(3).normal(size=(1, 32, 48, 19)).astype(np.float32)
    predict = lambda image: {"logits": jnp.asarray(logits), "attention_up": jnp.ones((1, 32, 48)) / 1536}  # noqa: E731
    write_pictures(tmp_path, predict, source, None, 1)
    (panels,) = drawn
    assert len(panels) == 5 and all(panel.title for panel in panels)  # image, prediction, label, score, attention
    picture = cv2.imread(str(tmp_path / "frame_0.png"))
    assert picture.shape[1] >= 512 and picture.shape[0] >= 256  # 32 x 48 frames enlarged to a readable size


def test_refused_writes_are_one_line(tmp_path, capsys, monkeypatch):
    np.save(tmp_path / "l.npy", np.zeros((1, 3, 4, 5), np.float32))
    args = ["score", "--logits", str(tmp_path / "l.npy"), "--methods", "msp"]
    real_open = os.open

    def refusing_open(path, *rest, **kwargs):  # a read-only or immutable --out (root ignores chmod)
        if str(path).startswith(str(tmp_path / "ro")):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *rest, **kwargs)

    monkeypatch.setattr(os, "open", refusing_open)
    _one_line_error(capsys, main([*args, "--out", str(tmp_path / "ro")]), "Permission denied")
    monkeypatch.setattr(atomic_io.tempfile, "mkstemp", lambda **kw: (_ for _ in ()).throw(
        OSError(30, "Read-only file system", kw["dir"])))  # the disk refuses a later write
    _one_line_error(capsys, main([*args, "--out", str(tmp_path / "late")]), "Read-only file system")
