"""One-line messages instead of tracebacks or silence: bad environment variables of a distributed
run, images above OpenCV's pixel limit, empty --methods, statistics files, a full disk, and
progress bars drawn where no terminal reads them."""
import errno
import io
import os
import struct
import time
import zlib

import numpy as np
import pytest

from jaxanom import sml
from jaxanom.cli import _parser, main
from jaxanom.data.image_io import read_rgb
from jaxanom.io import write_bytes_atomic, write_json_atomic
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
