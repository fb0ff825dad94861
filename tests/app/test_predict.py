"""``jaxanom predict`` on real frames (PNG, WebP, JPEG) with a tiny converted run: every format,
a kill and a rerun, a corrupt image, one-line errors; the *_superpixel methods' wiring."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import h5py
import jax
import numpy as np
import pytest

from conftest import REALDATA
from jaxanom.cli import main
from converted_run import SIZE, tiny_run  # noqa: F401  (the fixture)

@pytest.fixture(scope="module")
def real_frames():
    """One SMIYC RoadAnomaly21 PNG, one RoadObstacle21 WebP, one Road Anomaly JPEG."""
    paths = [REALDATA / "RoadAnomaly21" / "images" / "0.png", REALDATA / "RoadObstacle21" / "images" / "1.webp",
             REALDATA / "RoadAnomaly_sample" / "frames" / "cones02_Broadmoor_Manhole_Cones.jpg"]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        pytest.skip(f"real frames not found ({missing[0]}; set JAXANOM_REALDATA)")
    return paths


def snapshot(run: Path) -> dict:
    return {p.relative_to(run): p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file()}


def reference_msp(run: Path, path: Path) -> np.ndarray:
    """MSP at the image's size: the run's logits at SIZE (jaxanom's predictor), softmax in NumPy,
    bilinear resizing with OpenCV (half-pixel centres), as float16."""
    from jaxanom.app.evaluate import predictor
    from jaxanom.app.experiment import build_network, load_variables

    experiment, variables = load_variables(run)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)[..., ::-1]
    small = cv2.resize(np.ascontiguousarray(image), SIZE[::-1], interpolation=cv2.INTER_LINEAR)
    logits = np.asarray(predictor(build_network(experiment), variables)(small[None])["logits"][0], np.float64)
    p = np.exp(logits - logits.max(-1, keepdims=True))
    msp = (1 - (p / p.sum(-1, keepdims=True)).max(-1)).astype(np.float32)
    return cv2.resize(msp, image.shape[1::-1], interpolation=cv2.INTER_LINEAR), image.shape[:2]


def test_every_format_on_real_frames(tiny_run, real_frames, tmp_path, capsys):
    before = snapshot(tiny_run)
    out = tmp_path / "maps"
    args = ["predict", *map(str, real_frames), "--run", str(tiny_run), "--out", str(out), "--methods", "msp,energy",
            "--format", "npy,png,smiyc", "--dataset", "AnomalyTrack-all", "--size", "48x96", "--batch-size", "2",
            "--no-progress"]
    assert main(args) == 0
    assert "3 frames written" in capsys.readouterr().out
    assert snapshot(tiny_run) == before  # the run is only read
    for path in real_frames:
        expected, shape = reference_msp(tiny_run, path)
        for method in ("msp", "energy"):
            npy = np.load(out / "npy" / method / f"{path.stem}.npy")
            assert npy.dtype == np.float16 and npy.shape == shape
            with h5py.File(out / "anomaly_p" / method / "AnomalyTrack-all" / f"{path.stem}.hdf5", "r") as f:
                assert list(f.keys()) == ["value"]
                value = f["value"]
                assert value.dtype == np.float16 and value.shape == shape and value.compression == "gzip"
                np.testing.assert_array_equal(value[()], npy)
            picture = cv2.imread(str(out / "png" / method / f"{path.stem}.png"))
            assert 2 * 512 < picture.shape[1] < 2 * 1024 + 200 and picture.shape[0] > 300  # two readable panels
        # float16 rounding of the float32 map: half a unit in the last place, 2**-11 relative
        np.testing.assert_allclose(np.load(out / "npy" / "msp" / f"{path.stem}.npy").astype(np.float32), expected,
                                   rtol=2**-11, atol=1e-4)
    settings = json.loads((out / "settings.json").read_text())
    assert settings["methods"] == ["msp", "energy"] and settings["size"] == [48, 96]
    # a rerun with the same settings skips every frame (and drops what a killed run left unfinished)
    stale = out / "npy" / "msp" / f".{real_frames[0].stem}.npy.x1y2z3.tmp"
    stale.write_bytes(b"half")
    assert main(args) == 0
    assert "0 frames written, 3 already there" in capsys.readouterr().out
    assert not stale.exists()
    assert main([*args, "--size", "24x48"]) == 2
    assert "size=[48, 96], now size=[24, 48]" in capsys.readouterr().err


def test_native_size_and_folders_and_globs(tiny_run, tmp_path, capsys):
    rng = np.random.default_rng(0)
    folder = tmp_path / "images"
    folder.mkdir()
    for name, shape in (("a", (40, 72)), ("b", (40, 72)), ("c", (24, 40))):
        cv2.imwrite(str(folder / f"{name}.png"), rng.integers(0, 256, (*shape, 3), dtype=np.uint8))
    (folder / "notes.txt").write_text("not an image")
    out = tmp_path / "maps"
    assert main(["predict", str(folder), "--run", str(tiny_run), "--out", str(out), "--methods", "entropy",
                 "--batch-size", "2", "--no-progress"]) == 0
    assert np.load(out / "npy" / "entropy" / "c.npy").shape == (24, 40)
    assert np.load(out / "npy" / "entropy" / "a.npy").shape == (40, 72)
    out2 = tmp_path / "maps2"
    assert main(["predict", str(folder / "[ab].png"), "--run", str(tiny_run), "--out", str(out2), "--methods",
                 "entropy", "--no-progress"]) == 0
    assert sorted(p.name for p in (out2 / "npy" / "entropy").iterdir()) == ["a.npy", "b.npy"]
    # each frame is computed alone: the batch size and the frames beside it change no bit
    np.testing.assert_array_equal(np.load(out2 / "npy" / "entropy" / "a.npy"), np.load(out / "npy" / "entropy" / "a.npy"))


def _command(args):
    code = "import sys; from jaxanom.cli import main; sys.exit(main(sys.argv[1:]))"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    return [sys.executable, "-c", code, *args], env


def test_killed_and_rerun_resumes_with_the_same_results(tiny_run, real_frames, tmp_path):
    frames = [*real_frames, *(REALDATA / "RoadObstacle21" / "images" / f"{i}.webp" for i in (2, 3, 4))]
    common = ["--run", str(tiny_run), "--methods", "msp,entropy_superpixel", "--format", "npy,smiyc",
              "--dataset", "ObstacleTrack-all", "--size", "48x96", "--no-progress"]
    killed = tmp_path / "killed"
    command, env = _command(["predict", *map(str, frames), "--out", str(killed), *common])
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    last = killed / "anomaly_p" / "entropy_superpixel" / "ObstacleTrack-all"  # a frame's last file
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None and \
            not (last.is_dir() and any(p.suffix == ".hdf5" for p in last.iterdir())):
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    process.wait()
    done_before = {p.stem for p in last.glob("*.hdf5")}
    assert 0 < len(done_before) < len(frames), "the kill should land mid-run"
    for path in killed.rglob("*.npy"):  # whatever exists is complete
        np.load(path)
    for path in killed.rglob("*.hdf5"):
        with h5py.File(path, "r") as f:
            f["value"][()]
    # rerun: resumes (the claim marker of the killed process is the only clean-up it needs)
    (killed / ".jaxanom-claim").unlink()
    rerun = subprocess.run(_command(["predict", *map(str, frames), "--out", str(killed), *common])[0], env=env,
                           capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    assert f"{len(done_before)} already there" in rerun.stdout
    assert not [p for p in killed.rglob("*") if p.name.endswith(".tmp")]
    whole = tmp_path / "whole"
    assert main(["predict", *map(str, frames), "--out", str(whole), *common]) == 0
    files = sorted(p.relative_to(whole) for p in whole.rglob("*") if p.is_file() and p.suffix in (".npy", ".hdf5"))
    assert len(files) == 2 * 2 * len(frames)
    assert files == sorted(p.relative_to(killed) for p in killed.rglob("*") if p.suffix in (".npy", ".hdf5"))
    for name in files:
        if name.suffix == ".npy":
            np.testing.assert_array_equal(np.load(killed / name), np.load(whole / name))
        else:
            with h5py.File(killed / name, "r") as a, h5py.File(whole / name, "r") as b:
                np.testing.assert_array_equal(a["value"][()], b["value"][()])


def test_corrupt_image_stops_with_one_line(tiny_run, real_frames, tmp_path, capsys):
    folder = tmp_path / "images"
    folder.mkdir()
    good = real_frames[2].read_bytes()
    (folder / "a_good.jpg").write_bytes(good)
    (folder / "b_truncated.jpg").write_bytes(good[: len(good) // 2])
    (folder / "c_good.jpg").write_bytes(good)
    out = tmp_path / "maps"
    code = main(["predict", str(folder), "--run", str(tiny_run), "--out", str(out), "--methods", "msp",
                 "--size", "48x96", "--batch-size", "2", "--no-progress"])
    error = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(error) == 1 and "b_truncated.jpg" in error[0], error
    assert (out / "npy" / "msp" / "a_good.npy").is_file() and not (out / "npy" / "msp" / "c_good.npy").exists()


@pytest.mark.parametrize("extra, message", [
    (["--methods", "msp,nonsense"], "methods"),
    (["--methods", "sml"], "statistics"),
    (["--methods", "mmf"], "methods"),
    (["--format", "smiyc"], "dataset"),
    (["--format", "tiff"], "--format: expected names from"),
    (["--size", "48by96"], "--size"),
    (["--size", "0x96"], "--size"),
    (["--format", "smiyc", "--dataset", "../up"], "dataset"),
])
def test_bad_arguments_are_one_line_and_write_nothing(tiny_run, tmp_path, capsys, extra, message):
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.zeros((16, 16, 3), np.uint8))
    out = tmp_path / "maps"
    code = main(["predict", str(image), "--run", str(tiny_run), "--out", str(out), "--no-progress", *extra])
    error = capsys.readouterr().err.strip()
    assert code == 2 and message in error and len(error.splitlines()) == 1, error
    assert not out.exists()


def test_inputs_and_outputs_are_checked(tiny_run, tmp_path, capsys):
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.zeros((16, 16, 3), np.uint8))
    cases = [(["predict", str(tmp_path / "none.png"), "--out", str(tmp_path / "o")], "none.png"),
             (["predict", str(tmp_path / "*.jpg"), "--out", str(tmp_path / "o")], "names no image"),
             (["predict", str(image), "--out", str(tiny_run / "maps")], "inside --run"),
             (["predict", str(image), "--out", str(tmp_path)], "inside --out")]
    for args, message in cases:
        code = main([*args, "--run", str(tiny_run), "--methods", "msp", "--no-progress"])
        error = capsys.readouterr().err.strip()
        assert code == 2 and message in error and len(error.splitlines()) == 1, error
    assert not (tiny_run / "maps").exists()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.png").write_bytes(image.read_bytes())
    code = main(["predict", str(image), str(tmp_path / "other"), "--run", str(tiny_run), "--out",
                 str(tmp_path / "o"), "--methods", "msp"])
    assert code == 2 and "share the frame name" in capsys.readouterr().err


def test_float16_overflow_is_refused(tmp_path):
    from jaxanom.app.predict import PredictSettings, write_frame

    frame = {"name": "f", "image": np.zeros((2, 3, 3), np.uint8)}
    with pytest.raises(ValueError, match="float16"):
        write_frame(tmp_path, frame, {"energy": np.full((2, 3), -7e4, np.float32)},
                    PredictSettings(methods=("energy",)))
    assert not list(tmp_path.rglob("*.npy"))


def test_superpixel_methods_are_eq6_on_the_normalised_uncertainty():
    from jaxanom import superpixels
    from jaxanom import method_registry
    from jaxanom.mmf.postprocess import superpixel_score

    rng = np.random.default_rng(0)
    logits = rng.normal(size=(2, 24, 40, 5)).astype(np.float32) * 3
    images = rng.integers(0, 256, (2, 24, 40, 3), dtype=np.uint8)
    step = superpixels.scaled_step((24, 40))
    assert step == 1 and superpixels.scaled_step((256, 512)) == 8 and superpixels.scaled_step((1080, 1920)) == 32
    got = {name: np.asarray(method_registry.score(name, {"logits": logits, "image": images}, {"slic_step": 4}))
           for name in ("entropy_superpixel", "softmax_distance_superpixel")}
    p = np.exp(logits - logits.max(-1, keepdims=True))
    p /= p.sum(-1, keepdims=True)
    entropy = -(p * np.log2(p)).sum(-1) / np.log2(5)  # Eq. 1 over its maximum
    top = np.sort(p, axis=-1)
    distance = 1 - top[..., -1] + top[..., -2]  # Eq. 2
    k = superpixels.num_superpixels((24, 40), 4)
    for index in range(2):
        labels = superpixels.slic(superpixels.rgb_to_lab(images[index]), 4)
        for name, anomaly in (("entropy_superpixel", entropy), ("softmax_distance_superpixel", distance)):
            expected = superpixel_score(anomaly[index], p[index, ..., 0], labels, k)
            np.testing.assert_allclose(got[name][index], expected, atol=1e-5)
    with pytest.raises(ValueError, match="images"):
        method_registry.score("entropy_superpixel", {"logits": logits})


def test_statistics_of_another_network_are_refused(tiny_run, tmp_path, capsys):
    from jaxanom.sml import save_stats

    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.zeros((16, 16, 3), np.uint8))
    save_stats(tmp_path / "s.npz", np.zeros(3), np.ones(3), np.ones(3, np.int64))
    code = main(["predict", str(image), "--run", str(tiny_run), "--out", str(tmp_path / "o"), "--methods", "sml",
                 "--stats", str(tmp_path / "s.npz")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "3 classes" in error and "19" in error and not (tmp_path / "o").exists()


def test_size_check_names_sizes_the_network_refuses():
    import flax.linen as nn

    from jaxanom.app.predict import size_check

    class Strided(nn.Module):  # logits at half resolution; refuses sizes that are not multiples of 8
        @nn.compact
        def __call__(self, x, train=False):
            if x.shape[1] % 8 or x.shape[2] % 8:
                raise ValueError(f"expected multiples of 8, got {x.shape[1:3]}")
            return {"logits": nn.Conv(4, (3, 3), strides=(2, 2))(x)}

    model = Strided()
    variables = model.init(jax.random.key(0), np.zeros((1, 8, 8, 3), np.float32))
    check = size_check(model, variables)
    with pytest.raises(ValueError, match=r"does not run on 20x32 images \(a\.png\): expected multiples of 8"):
        check((20, 32), "a.png")
    with pytest.raises(ValueError, match=r"logits are \(8, 16\) for 16x32 images"):
        check((16, 32), "b.png")
