"""One-line messages instead of tracebacks or silence: bad environment variables of a distributed
run, images above OpenCV's pixel limit, empty --methods, statistics files, a full disk, and
progress bars drawn where no terminal reads them."""
import errno
import io
import json
import os
import struct
import time
import zlib

import numpy as np
import pytest

from jaxanom import sml
from jaxanom.app.commands.inputs import with_overrides
from jaxanom.app.experiment import Experiment, jsonable
from jaxanom.cli import _parser, main
from jaxanom.data.image_io import read_rgb
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.train.checkpoint import Checkpointer
from jaxanom.train.sharding import initialize_distributed


@pytest.mark.parametrize("env, message", [
    ({"JAX_COORDINATOR_ADDRESS": "nonsense", "JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": "0"},
     "JAX_COORDINATOR_ADDRESS: expected host:port"),
    ({"JAX_COORDINATOR_ADDRESS": "127.0.0.1:99999", "JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": "1"},
     "port from 1 to 65535, got '127.0.0.1:99999'"),
    ({"JAXANOM_DISTRIBUTED_TIMEOUT": "abc"}, "JAXANOM_DISTRIBUTED_TIMEOUT: expected an integer >= 1, got 'abc'"),
    ({"JAXANOM_DISTRIBUTED_TIMEOUT": "0"}, "JAXANOM_DISTRIBUTED_TIMEOUT: expected an integer >= 1, got '0'"),
    ({"JAXANOM_DISTRIBUTED_TIMEOUT": "-5"}, "JAXANOM_DISTRIBUTED_TIMEOUT: expected an integer >= 1, got '-5'"),
])
def test_bad_distributed_variables_are_refused_before_joining(monkeypatch, env, message):
    import jax

    for name in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("JAXANOM_DISTRIBUTED_TIMEOUT", "30")  # a wait, where one happens, would show
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    collectives = jax.config.jax_cpu_collectives_implementation
    start = time.monotonic()
    with pytest.raises(ValueError, match=message):
        initialize_distributed()
    assert time.monotonic() - start < 5 and not jax.distributed.is_initialized()
    assert jax.config.jax_cpu_collectives_implementation == collectives


def _png_header_only(width: int, height: int) -> bytes:
    """A grey PNG announcing ``width`` x ``height`` with a first scrap of pixel data (132 kB would hold all)."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + chunk(b"IEND", b""))


def test_an_image_above_opencvs_pixel_limit_is_one_line_naming_it(tmp_path):
    path = tmp_path / "huge.png"
    path.write_bytes(_png_header_only(33000, 33000))
    with pytest.raises(ValueError, match=r"image: cannot decode .*huge\.png \(more pixels than OpenCV decodes"):
        read_rgb(path)


@pytest.mark.parametrize("command", [["evaluate", "--run", "r", "--dataset", "synthetic", "--path", "anomaly"],
                                     ["score", "--logits", "l.npy"], ["predict", "x.png", "--run", "r"]])
def test_empty_methods_are_refused_not_read_as_the_default(command, capsys):
    with pytest.raises(SystemExit):
        _parser().parse_args([*command, "--out", "o", "--methods", ""])
    assert "--methods: expected comma-separated method names, got ''" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _parser().parse_args([*command, "--out", "o", "--methods", "msp,"])
    assert _parser().parse_args([*command, "--out", "o", "--methods", "msp,entropy"]).methods == "msp,entropy"


@pytest.mark.parametrize("command", [["predict", "x.png", "--run", "r", "--out", "o"], ["train", "--out", "o"],
                                     ["demo"]])
def test_progress_bars_only_where_stderr_is_a_terminal(command, monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr("sys.stderr", io.StringIO())
    assert _parser().parse_args(command).no_progress is True  # a log file or a pipe
    monkeypatch.setattr("sys.stderr", Terminal())
    assert _parser().parse_args(command).no_progress is False
    assert _parser().parse_args([*command, "--no-progress"]).no_progress is True


def test_save_stats_refuses_what_load_stats_would_naming_the_classes(tmp_path):
    mean, counts = np.zeros(4, np.float32), np.full(4, 10)
    for std, message in [(np.array([1, np.nan, 1, 0], np.float32), r"std must be finite and > 0; classes \[1, 3\]"),
                         (np.array([1, 1, np.inf, 1], np.float32), r"std .* classes \[2\] have \[inf\]")]:
        with pytest.raises(ValueError, match=message):
            sml.save_stats(tmp_path / "s.npz", mean, std, counts)
        assert not (tmp_path / "s.npz").exists()
    with pytest.raises(ValueError, match=r"mean must be finite; classes \[0\] have \[nan\]"):
        sml.save_stats(tmp_path / "s.npz", np.array([np.nan, 0, 0, 0]), np.ones(4), counts)
    with pytest.raises(ValueError, match=r"counts must be >= 0; classes \[3\] have \[-1\]"):
        sml.save_stats(tmp_path / "s.npz", mean, np.ones(4), np.array([1, 2, 3, -1]))
    sml.save_stats(tmp_path / "s.npz", mean, np.ones(4), counts)
    assert sml.load_stats(tmp_path / "s.npz")[2].tolist() == counts.tolist()


def test_a_stats_file_that_is_no_npz_says_what_was_expected(tmp_path, capsys):
    picture = tmp_path / "some.png"
    picture.write_bytes(_png_header_only(4, 4))
    with pytest.raises(ValueError, match=r"is not a readable \.npz file .*the statistics \.npz that jaxanom fit-stats"):
        sml.load_stats(picture)
    np.save(tmp_path / "logits.npy", np.zeros((1, 4, 4, 3), np.float32))
    assert main(["score", "--logits", str(tmp_path / "logits.npy"), "--stats", str(picture), "--methods", "sml",
                 "--layout", "NHWC", "--out", str(tmp_path / "o")]) == 2
    error = capsys.readouterr().err
    assert "fit-stats" in error and "pickle" not in error and len(error.strip().splitlines()) == 1


def test_a_full_disk_names_the_file_it_could_not_write(tmp_path, capsys, monkeypatch):
    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as fsync reports it: no file name

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError) as error:
        write_bytes_atomic(tmp_path / "a.bin", b"x")
    assert error.value.filename == str(tmp_path / "a.bin") and list(tmp_path.iterdir()) == []
    with pytest.raises(OSError, match="b.json"):
        write_json_atomic(tmp_path / "b.json", {})
    np.save(tmp_path / "logits.npy", np.zeros((1, 4, 4, 3), np.float32))
    assert main(["score", "--logits", str(tmp_path / "logits.npy"), "--methods", "msp", "--layout", "NHWC",
                 "--out", str(tmp_path / "o")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("jaxanom score: error: No space left on device: ") and "msp.npy" in error, error
    assert [p for p in tmp_path.rglob("*") if p.name != "logits.npy"] == []  # nothing half-written is left


def test_a_library_bug_keeps_its_traceback_and_bad_input_names_the_flag(monkeypatch, tmp_path, capsys):
    """A plain ValueError from deep code is a bug, not bad input: it propagates (a traceback), while an
    InputError is one line with its argument and mentions spelled as the command's flags."""
    from jaxanom.app.commands import score
    from jaxanom.errors import InputError

    argv = ["score", "--logits", str(tmp_path / "l.npy"), "--out", str(tmp_path / "o")]

    def bug(**settings):
        raise ValueError("a shape mismatch deep in the library")

    monkeypatch.setattr(score, "score", bug)
    with pytest.raises(ValueError, match="deep in the library"):
        main(argv)

    def bad_input(**settings):
        raise InputError("any_layout", ": not with {layout} NHWC; see {plugins}", mentions=("layout", "plugins"))

    monkeypatch.setattr(score, "score", bad_input)
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == "jaxanom score: error: --any-layout: not with --layout NHWC; see --plugin"
    assert str(InputError("any_layout", ": not with {layout} NHWC", mentions=("layout",))) == \
        "any_layout: not with layout NHWC"


@pytest.mark.parametrize("setting, message", [
    ("train.ignore=300", "experiment: train.ignore: the synthetic data marks void pixels 255; expected 255, got 300"),
    ("train.ignore=3", "train.ignore: the synthetic data marks void pixels 255; expected 255, got 3"),
    ("num_classes=3", "num_classes: the synthetic data has 19 classes (0..18); expected >= 19, got 3"),
])
def test_train_values_that_do_not_fit_the_data_are_refused_before_anything_is_written(tmp_path, capsys, setting,
                                                                                      message):
    run = tmp_path / "run"
    assert main(["train", "--out", str(run), "--steps", "2", "--set", setting, "--no-progress"]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and len(error.splitlines()) == 1, error
    assert not run.exists()
    run.mkdir()  # a folder an earlier version left: its experiment.json alone, with the value in it
    (run / "experiment.json").write_text(json.dumps(jsonable(with_overrides(Experiment(), [setting]))))
    assert main(["train", "--out", str(run), "--resume", "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert main(["train", "--out", str(run), "--steps", "2", "--no-progress"]) == 2  # fixed: names what differs
    error = capsys.readouterr().err
    assert "never reached its first checkpoint" in error and "--resume" not in error, error


def test_a_start_that_ended_before_its_first_checkpoint_does_not_block_its_rerun(tmp_path, monkeypatch, capsys):
    import jaxanom.app.experiment as app

    def crash(experiment, out, **_):  # a start killed after writing experiment.json
        write_json_atomic(out / "experiment.json", jsonable(experiment))
        raise KeyboardInterrupt

    run, argv = tmp_path / "run", ["train", "--out", str(tmp_path / "run"), "--steps", "2", "--no-progress"]
    monkeypatch.setattr(app, "run_training", crash)
    assert main(argv) == 130 and [p.name for p in run.iterdir()] == ["experiment.json"]
    handed = []
    monkeypatch.setattr(app, "run_training", lambda experiment, out, **_: handed.append(experiment))
    assert main([*argv, "--batch-size", "4"]) == 2  # another experiment: not started over the file
    error = capsys.readouterr().err.strip()
    assert ("--out " in error and "never reached its first checkpoint" in error and "batch_size is 8 there, 4 here"
            in error and "--resume starts that one" in error), error
    assert main([*argv, "--steps", "3"]) == 0 and handed[-1].train.steps == 3  # the same command: a fresh start
    (run / "notes.txt").write_text("mine")
    assert main(argv) == 2 and "not empty" in capsys.readouterr().err  # nothing but the run's own file


def test_resume_errors_name_the_flags_and_advise_resume(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "experiment.json").write_text(json.dumps(jsonable(with_overrides(Experiment(), ["train.steps=6"]))))
    with Checkpointer(run / "checkpoints") as checkpointer:  # 3 steps trained on the schedule of 6
        checkpointer.save(3, {"x": np.zeros(2, np.float32)})
    assert main(["train", "--out", str(run), "--resume", "--batch-size", "4", "--no-progress"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"jaxanom train: error: --out: {run} holds a run of a different experiment: batch_size "
                            "is 8 there, 4 here; --resume continues that run with its own settings"), error
    assert main(["train", "--out", str(run), "--resume", "--steps", "9", "--no-progress"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"jaxanom train: error: --steps: the run in {run} has 6 steps") and "run_dir" not in error
    assert f"resume it with 6 steps, start a new run from its weights (--init-from {run})" in error, error
    assert main(["train", "--out", str(tmp_path / "none"), "--resume", "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == (f"jaxanom train: error: --out {tmp_path / 'none'}: holds no run to "
                                               "resume (no experiment.json); start one there without --resume")
    (tmp_path / "empty").mkdir()
    assert main(["evaluate", "--run", str(tmp_path / "empty"), "--dataset", "synthetic", "--path", "anomaly", "--out",
                 str(tmp_path / "o")]) == 2
    assert (f"error: --run {tmp_path / 'empty'}: not a run folder: it holds no experiment.json"
            in capsys.readouterr().err)


def test_init_modules_need_init_from_which_is_stored_absolute_however_given(tmp_path, monkeypatch, capsys):
    import jaxanom.app.experiment as app

    handed = []
    monkeypatch.setattr(app, "run_training", lambda experiment, out, **_: handed.append(experiment))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "source").mkdir()
    (tmp_path / "source" / "experiment.json").write_text(json.dumps(jsonable(Experiment())))
    for flags in (["--init-modules", "backbone"], ["--set", "init_modules=backbone"]):
        assert main(["train", "--out", "a", *flags, "--no-progress"]) == 2
        assert ("error: --init-modules takes modules from the run of --init-from, which is not given"
                in capsys.readouterr().err)
        assert not (tmp_path / "a").exists() and handed == []
    for k, flags in enumerate((["--init-from", "source"], ["--set", "init_from=source"])):
        assert main(["train", "--out", f"b{k}", *flags, "--init-modules", "backbone", "--no-progress"]) == 0
        assert (handed[-1].init_from, handed[-1].init_modules) == (str(tmp_path / "source"), ("backbone",))
    assert main(["train", "--out", "c", "--set", "init_from=nowhere", "--no-progress"]) == 2
    assert "error: --init-from nowhere: " in capsys.readouterr().err
