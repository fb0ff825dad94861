"""Commands that read a run: they never write into it, leave nothing outside --out when killed,
print no warnings of their own libraries, and say in one line what is wrong with their frames."""
import logging
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

import jaxanom.app.evaluate
from jaxanom.cli import main
from jaxanom.app.outputs import CLAIM, claim, release_claims
from converted_run import tiny_run, write_tiny_cityscapes  # noqa: F401  (tiny_run: a module-scoped fixture, a converted tiny DeepLabV3+)


def _tree(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*")}


def _one_line(capsys, code: int, *parts: str) -> str:
    error = capsys.readouterr().err.strip()
    assert code == 2 and len(error.splitlines()) == 1 and all(p in error for p in parts), error
    return error


def _smiyc(root: Path) -> Path:
    rng = np.random.default_rng(1)
    for name in ("a", "b"):
        (root / "images").mkdir(parents=True, exist_ok=True)
        (root / "labels_masks").mkdir(exist_ok=True)
        cv2.imwrite(str(root / "images" / f"{name}.png"), rng.integers(0, 256, (32, 64, 3), dtype=np.uint8))
        label = np.zeros((32, 64), np.uint8)
        label[8:20, 10:30] = 1
        cv2.imwrite(str(root / "labels_masks" / f"{name}_labels_semantic.png"), label)
    return root


@pytest.mark.parametrize("command", ["evaluate", "fit-stats"])
def test_readers_refuse_an_out_inside_the_run(tiny_run, tmp_path, capsys, command):
    before = _tree(tiny_run)
    if command == "evaluate":
        args = ["evaluate", "--run", str(tiny_run), "--dataset", "smiyc", "--path", str(_smiyc(tmp_path / "t")),
                "--track", "anomaly", "--methods", "msp", "--out", str(tiny_run / "checkpoints" / "1")]
    else:
        args = ["fit-stats", "--run", str(tiny_run), "--missing", "pooled", "--out", str(tiny_run / "stats.npz")]
    _one_line(capsys, main(args), "--out", "lies inside --run")
    assert _tree(tiny_run) == before


def test_evaluate_spills_its_maps_into_its_out_where_a_take_over_removes_them(tiny_run, tmp_path, monkeypatch):
    spills = []
    component_pass = jaxanom.app.evaluate._component_pass

    def recording(folder, *args):
        spills.append((folder, sorted(p.name for p in folder.iterdir())))
        return component_pass(folder, *args)

    monkeypatch.setattr(jaxanom.app.evaluate, "_component_pass", recording)
    out = tmp_path / "out"
    assert main(["evaluate", "--run", str(tiny_run), "--dataset", "smiyc", "--path", str(_smiyc(tmp_path / "t")),
                 "--track", "anomaly", "--methods", "msp", "--out", str(out)]) == 0
    (folder, files), = spills
    assert folder.parent == out and files == ["label_0.npy", "label_1.npy", "msp_0.npy", "msp_1.npy"]
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]
    folder.mkdir()  # what a kill -9 during the component pass leaves, under a claim of a process now gone
    (folder / "msp_0.npy").write_bytes(b"x")
    (out / CLAIM).write_text(f"{2**22 + 1} {os.uname().nodename} -\n")
    claim(out / CLAIM, out)  # what the next command on this folder does first
    release_claims()
    assert not folder.exists()


def test_reading_a_run_logs_no_warning(tiny_run, caplog):
    from jaxanom.app.experiment import load_variables

    with caplog.at_level(logging.INFO, logger="absl"):
        load_variables(tiny_run)
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []


def test_fit_stats_on_cityscapes_frames_of_two_sizes_suggests_size(tiny_run, tmp_path, capsys):
    mixed = write_tiny_cityscapes(tmp_path / "mixed", [(32, 64), (48, 64)], labels=True)
    _one_line(capsys, main(["fit-stats", "--run", str(tiny_run), "--cityscapes", str(mixed), "--out",
                            str(tmp_path / "a.npz")]),
              "frames differ in size", "city_000000_000000 is 32x64", "city_000000_000001 is 48x64", "--size")
    assert not (tmp_path / "a.npz").exists()


def test_fit_stats_on_cityscapes_needs_no_labels(tiny_run, tmp_path):
    images = write_tiny_cityscapes(tmp_path / "images", [(32, 64), (48, 64)], labels=False)
    assert main(["fit-stats", "--run", str(tiny_run), "--cityscapes", str(images), "--size", "32x64",
                 "--missing", "pooled", "--out", str(tmp_path / "b.npz")]) == 0
    assert (tmp_path / "b.npz").is_file()


def test_fit_stats_refuses_a_converted_run_without_frames(tiny_run, tmp_path, capsys):
    """A converted run's experiment.json says ``data: synthetic`` (jaxanom's default), yet its network
    never saw synthetic scenes: fitting on them would be silently wrong."""
    out = tmp_path / "s.npz"
    _one_line(capsys, main(["fit-stats", "--run", str(tiny_run), "--frames", "2", "--missing", "pooled",
                            "--out", str(out)]), "error: --cityscapes DIR needed", "step 0", "convert-weights")
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_statistics_name_their_frames_in_every_command_that_reads_them(tiny_run, tmp_path, capsys):
    import json

    from jaxanom import sml

    images = write_tiny_cityscapes(tmp_path / "cs", [(40, 72), (40, 72)], labels=False)
    stats = tmp_path / "s.npz"
    assert main(["fit-stats", "--run", str(tiny_run), "--cityscapes", str(images), "--size", "32x64",
                 "--missing", "pooled", "--out", str(stats)]) == 0
    record = {"set": "cityscapes train", "folder": str(images.resolve()), "count": 2, "size": [32, 64]}
    assert sml.load_stats_info(stats)["frames"] == record
    line = f"fitted on 2 frames of cityscapes train in {images.resolve()} at 32x64"
    assert line in (printed := capsys.readouterr().out), printed
    old = tmp_path / "old.npz"  # a file written before the record: still read, and said so
    sml.save_stats(old, *sml.load_stats(stats))
    smiyc = _smiyc(tmp_path / "t")
    for file, said, frames in ((stats, line, record), (old, "frames not recorded", "not recorded")):
        out = tmp_path / f"eval_{file.stem}"
        assert main(["evaluate", "--run", str(tiny_run), "--dataset", "smiyc", "--path", str(smiyc), "--track", "none",
                     "--methods", "sml", "--stats", str(file), "--out", str(out)]) == 0
        assert said in capsys.readouterr().out
        assert json.loads((out / "metrics.json").read_text())["sml_statistics"]["frames"] == frames
        assert main(["predict", str(smiyc / "images"), "--run", str(tiny_run), "--methods", "sml", "--stats", str(file),
                     "--out", str(tmp_path / f"predict_{file.stem}")]) == 0
        assert said in capsys.readouterr().out
