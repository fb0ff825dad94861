"""Recovery after a kill, and runs never replaced half-way."""
import errno
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from jaxanom.app import outputs
from jaxanom.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _one_line(capsys, code, *fragments, exit_code=2):
    error = capsys.readouterr().err.strip()
    assert code == exit_code and len(error.splitlines()) == 1 and "Traceback" not in error, error
    for fragment in fragments:
        assert fragment in error, error
    return error


def _gone_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()  # reaped: its PID names no process now
    return child.pid


def _logits(tmp_path, bad_label=False):
    rng = np.random.default_rng(0)
    np.save(tmp_path / "logits.npy", rng.normal(size=(2, 3, 4, 5)).astype(np.float32))
    labels = rng.choice(np.array([0, 1], np.uint8), size=(2, 4, 5))
    if bad_label:
        labels[1, 0, 0] = 7
    np.save(tmp_path / "labels.npy", labels)
    return ["score", "--logits", str(tmp_path / "logits.npy"), "--labels", str(tmp_path / "labels.npy"),
            "--methods", "msp"]


@pytest.mark.parametrize("marker_text", ["{pid}\n", "{pid} {host} 12345\n"])  # this version's and the last's
def test_a_claim_of_a_gone_process_is_taken_over_with_its_temporaries(tmp_path, capsys, marker_text):
    out = tmp_path / "out"
    (out / "scores").mkdir(parents=True)
    (out / outputs.CLAIM).write_text(marker_text.format(pid=_gone_pid(), host=socket.gethostname()))
    leftovers = [out / ".metrics.json.k2j3.tmp", out / "scores" / ".msp.npy.x9y8.tmp"]
    for path in leftovers:
        path.write_bytes(b"half")
    assert main([*_logits(tmp_path), "--out", str(out), "--overwrite"]) == 0
    error = capsys.readouterr().err
    assert "took over" in error and "removed 2 unfinished" in error and len(error.strip().splitlines()) == 1
    assert not any(path.exists() for path in leftovers)
    assert (out / "scores" / "msp.npy").is_file() and not (out / outputs.CLAIM).exists()


@pytest.mark.parametrize("owner", ["live", "other host", "not a marker"])
def test_a_claim_of_a_live_process_or_another_host_still_refuses(tmp_path, capsys, owner):
    out = tmp_path / "out"
    out.mkdir()
    text = {"live": f"{os.getppid()} {socket.gethostname()} -", "other host": f"{_gone_pid()} elsewhere.example -",
            "not a marker": "hello"}[owner]
    (out / outputs.CLAIM).write_text(text)
    (out / ".x.tmp").write_bytes(b"theirs")
    _one_line(capsys, main([*_logits(tmp_path), "--out", str(out), "--overwrite"]), "another jaxanom command")
    assert (out / outputs.CLAIM).read_text() == text and (out / ".x.tmp").exists()


def test_a_file_claim_of_a_killed_process_is_taken_over(tmp_path, capsys):
    target = tmp_path / "stats.npz"
    script = ("import os, signal, sys; from pathlib import Path; from jaxanom.app.outputs import claim, CLAIM; "
              "p = Path(sys.argv[1]); claim(p.parent / (p.name + CLAIM), p); "
              "(p.parent / ('.' + p.name + '.abc.tmp')).write_bytes(b'half'); os.kill(os.getpid(), signal.SIGKILL)")
    killed = subprocess.run([sys.executable, "-c", script, str(target)], env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert killed.returncode == -signal.SIGKILL
    assert (tmp_path / f"stats.npz{outputs.CLAIM}").exists()
    outputs.claim(tmp_path / f"stats.npz{outputs.CLAIM}", tmp_path / "stats.npz")
    outputs.release_claims()
    assert "took over" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


_SLOW_COMMAND = """
import sys, time
from pathlib import Path
import numpy as np
from jaxanom.app import outputs
from jaxanom.cli import main, score
from jaxanom.io import NpyWriter

def slow(args):  # a command half-way through writing its outputs
    out = outputs.out_folder(args.out, args.overwrite)
    with NpyWriter(out / "scores" / "msp.npy", (2, 3), np.float32) as writer:
        writer.write(np.zeros(3))
        Path(sys.argv[2]).write_text("ready")
        time.sleep(120)

score.run = slow
sys.exit(main(["score", "--logits", "x.npy", "--out", sys.argv[1]]))
"""


def test_sigterm_unwinds_like_ctrl_c_leaving_nothing(tmp_path):
    out, ready = tmp_path / "out", tmp_path / "ready"
    child = subprocess.Popen([sys.executable, "-c", _SLOW_COMMAND, str(out), str(ready)],
                             env={**os.environ, "PYTHONPATH": str(ROOT)}, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not ready.exists() and child.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert ready.exists(), child.stderr.read() if child.poll() is not None else "timed out"
        assert list(out.rglob("*.tmp")) and (out / outputs.CLAIM).exists()
        child.send_signal(signal.SIGTERM)
        error = child.communicate(timeout=60)[1].strip()
    finally:
        child.kill()
    assert child.returncode == 128 + signal.SIGTERM
    assert error.endswith("terminated (SIGTERM); nothing half-written is left"), error
    assert not out.exists()  # the claim, the temporary and the empty folders it made are gone


def test_a_failed_score_leaves_nothing_that_blocks_its_retry(tmp_path, capsys):
    out = tmp_path / "out"
    _one_line(capsys, main([*_logits(tmp_path, bad_label=True), "--out", str(out)]), "image 1")
    assert not out.exists()
    out.mkdir()  # a folder the user made stays, empty
    _one_line(capsys, main([*_logits(tmp_path, bad_label=True), "--out", str(out)]), "image 1")
    assert out.is_dir() and not list(out.iterdir())
    assert main([*_logits(tmp_path), "--out", str(out)]) == 0  # the retry needs no --overwrite


def test_convert_weights_overwrite_refuses_to_replace_a_run(tmp_path, capsys):
    run = tmp_path / "run"
    (run / "checkpoints" / "300").mkdir(parents=True)
    (run / "experiment.json").write_text('{"trained": true}')
    np.savez(tmp_path / "w.npz", x=np.zeros(2, np.float32))
    before = sorted((str(p), p.stat().st_mtime_ns) for p in run.rglob("*"))
    _one_line(capsys, main(["convert-weights", "--from", "torchvision-resnet18", str(tmp_path / "w.npz"), str(run),
                            "--overwrite"]), "holds a run (experiment.json, checkpoints)", "delete that run")
    assert sorted((str(p), p.stat().st_mtime_ns) for p in run.rglob("*")) == before


def _tiny_conversion(tmp_path, monkeypatch):
    """A weights file and a stand-in for the conversion (a 4 MiB network): the writing is under test."""
    import types

    import jaxanom.weights

    np.savez(tmp_path / "w.npz", x=np.zeros(2, np.float32))
    model = types.SimpleNamespace(attention=None, cudam_position="deep", output_stride=16, num_classes=19)
    variables = {"params": {"w": np.ones((1024, 1024), np.float32)}}
    monkeypatch.setattr(jaxanom.weights, "from_torch", lambda *args, **kwargs: (model, variables))
    return tmp_path / "w.npz"


def test_convert_weights_writes_the_run_it_staged(tmp_path, monkeypatch):
    weights = _tiny_conversion(tmp_path, monkeypatch)
    assert main(["convert-weights", "--from", "torchvision-resnet18", str(weights), str(tmp_path / "run")]) == 0
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["checkpoints", "experiment.json"]
    assert [p.name for p in (tmp_path / "run" / "checkpoints").iterdir()] == ["0"]


def test_convert_weights_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    import shutil

    import jaxanom.app.runs

    weights = _tiny_conversion(tmp_path, monkeypatch)
    real = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda path: real(path)._replace(free=1 << 20))
    _one_line(capsys, main(["convert-weights", "--from", "torchvision-resnet18", str(weights), str(tmp_path / "a")]),
              "needs 8.0 MiB", "1.0 MiB free", "nothing was left behind")
    assert not (tmp_path / "a").exists()
    monkeypatch.setattr(shutil, "disk_usage", real)

    def half_written(folder, *args):  # a writer that fills the disk half-way
        (Path(folder) / "checkpoints" / "0").mkdir(parents=True)
        (Path(folder) / "checkpoints" / "0" / "part").write_bytes(b"x" * 100)
        raise OSError(errno.ENOSPC, "No space left on device", str(folder))

    monkeypatch.setattr(jaxanom.app.runs, "write_run", half_written)
    (tmp_path / "b").mkdir()
    _one_line(capsys, main(["convert-weights", "--from", "torchvision-resnet18", str(weights), str(tmp_path / "b")]),
              "No space left on device", "nothing was left behind")
    assert list((tmp_path / "b").iterdir()) == []



def test_a_diverging_run_is_one_line_naming_the_last_good_step_and_what_to_change(tmp_path, capsys, monkeypatch):
    import jaxanom.app.experiment
    from jaxanom.train.segmenter import NonFiniteLossError

    def diverging(experiment, run_dir, **kwargs):  # what the loop raises (tests/train/test_train_segmenter.py)
        jaxanom.app.experiment.write_json_atomic(Path(run_dir) / "experiment.json", jaxanom.app.experiment.jsonable(experiment))
        raise NonFiniteLossError("loss nan, gradient norm nan at step 2: training stopped; last good checkpoint: "
                                 f"step 1 in {run_dir}/checkpoints")

    monkeypatch.setattr(jaxanom.app.experiment, "run_training", diverging)
    run = tmp_path / "run"
    _one_line(capsys, main(["train", "--out", str(run), "--attention", "none", "--no-progress"]),
              "the run diverged", "last good checkpoint: step 1", "lower learning rate (--set train.optim.lr=..., now 0.01)")
    _one_line(capsys, main(["train", "--resume", "--out", str(run), "--no-progress"]),
              "the run diverged", "--resume repeats the same steps")
