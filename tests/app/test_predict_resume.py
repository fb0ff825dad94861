"""``jaxanom predict`` reruns: what a resume may keep (maps of the same statistics and weights, any
batch size), what never blocks one (a failed start, its own outputs), frames named as given
(symlinks), each frame scored alone, and a device out-of-memory as one line."""
import os
import shutil

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.cli import main
from converted_run import tiny_run  # noqa: F401 (the module fixture: a tiny converted run)


def write_images(folder, names, shape=(48, 96), seed=0):
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        cv2.imwrite(str(folder / name), rng.integers(0, 256, (*shape, 3), dtype=np.uint8))
    return [folder / name for name in names]


def save_random_stats(path, seed):
    from jaxanom.sml import save_stats

    rng = np.random.default_rng(seed)
    save_stats(path, rng.normal(size=19), rng.uniform(0.5, 2, 19), np.full(19, 100, np.int64))


def predict(capsys, *args):
    code = main(["predict", *map(str, args), "--no-progress"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip()


def test_maps_are_resumed_only_from_the_same_statistics_and_weights(tiny_run, tmp_path, capsys):  # noqa: F811
    """Fingerprints of contents, not paths: a moved run resumes, re-fitted statistics or other weights do not."""
    from jaxanom.app.experiment import build_network, load_variables
    from jaxanom.app.runs import write_run

    a, b = write_images(tmp_path / "images", ["a.png", "b.png"])
    stats, out = tmp_path / "stats.npz", tmp_path / "maps"
    save_random_stats(stats, 1)
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    common = ["--stats", stats, "--methods", "sml", "--out", out]
    code, printed, error = predict(capsys, a, b, "--run", run, *common)
    assert code == 0 and "2 frames written" in printed, error
    # the same contents in another folder: a resume
    shutil.move(run, tmp_path / "moved")
    code, printed, error = predict(capsys, a, b, "--run", tmp_path / "moved", *common)
    assert code == 0 and "0 frames written, 2 already there" in printed, error
    # statistics re-fitted into the same file: refused in one line; --overwrite recomputes
    save_random_stats(stats, 2)
    code, printed, error = predict(capsys, a, b, "--run", tmp_path / "moved", *common)
    assert code == 2 and "statistics" in error and len(error.splitlines()) == 1, error
    code, printed, error = predict(capsys, a, "--run", tmp_path / "moved", *common, "--overwrite")
    assert code == 0 and "1 frames written" in printed, error
    assert not (out / "npy" / "sml" / "b.npy").exists()  # made with the old statistics: a resume must not keep it
    fresh = tmp_path / "fresh"
    code, printed, error = predict(capsys, a, "--run", tmp_path / "moved", "--stats", stats, "--methods", "sml",
                                   "--out", fresh)
    assert code == 0, error
    np.testing.assert_array_equal(np.load(out / "npy" / "sml" / "a.npy"), np.load(fresh / "npy" / "sml" / "a.npy"))
    # other weights in the same run folder: refused
    experiment, variables = load_variables(tmp_path / "moved")
    shutil.rmtree(tmp_path / "moved")
    changed = jax.tree.map(lambda v: v * 1.5, variables)
    write_run(tmp_path / "moved", experiment.model, build_network(experiment), changed)
    code, printed, error = predict(capsys, a, "--run", tmp_path / "moved", *common)
    assert code == 2 and "network" in error and len(error.splitlines()) == 1, error


def test_a_failed_start_and_the_batch_size_block_no_rerun(tiny_run, tmp_path, capsys):  # noqa: F811
    image, out = tmp_path / "x.png", tmp_path / "maps"
    image.write_bytes(b"not a png")
    common = ["--run", tiny_run, "--methods", "msp", "--out", out]
    code, printed, error = predict(capsys, image, *common)
    assert code == 2 and "x.png" in error, error
    assert not [p for p in out.rglob("*") if p.is_file() and p.name != "settings.json"]
    write_images(tmp_path, ["x.png"])  # the image mended, the rerun with other settings
    code, printed, error = predict(capsys, image, *common, "--size", "48x96")
    assert code == 0 and "1 frames written" in printed, error
    code, printed, error = predict(capsys, image, *common, "--size", "48x96", "--batch-size", "3")
    assert code == 0 and "0 frames written, 1 already there" in printed, error
    code, printed, error = predict(capsys, image, *common, "--size", "48x96", "--overwrite")
    assert code == 0 and "1 frames written, 0 already there" in printed, error  # --overwrite recomputes
    code, printed, error = predict(capsys, image, *common, "--size", "32x64", "--overwrite")  # other settings
    assert code == 0 and "1 frames written" in printed and "removed 1 maps" in printed, error


def test_frames_are_named_as_given_and_a_recursive_glob_skips_its_own_outputs(tiny_run, tmp_path, capsys):  # noqa: F811
    # a folder of links into a content-addressed store (git-annex, DVC): two frames share one file
    (target,) = write_images(tmp_path / "store", ["SHA256E-s1234--0a1b2c.png"])
    tree = tmp_path / "tree"
    (tree / "images").mkdir(parents=True)
    for name in ("0.png", "1.png"):
        os.symlink(target, tree / "images" / name)
    command = [f"{tree}/**/*.png", "--run", tiny_run, "--methods", "msp", "--format", "npy,png", "--size", "48x96",
               "--out", tree / "pred"]
    code, printed, error = predict(capsys, *command)
    assert code == 0 and "2 frames written" in printed, error
    assert sorted(p.name for p in (tree / "pred" / "npy" / "msp").iterdir()) == ["0.npy", "1.npy"]
    np.testing.assert_array_equal(np.load(tree / "pred" / "npy" / "msp" / "0.npy"),
                                  np.load(tree / "pred" / "npy" / "msp" / "1.npy"))
    # the glob now also matches pred/png/msp/0.png and 1.png: never inputs
    code, printed, error = predict(capsys, *command)
    assert code == 0 and "0 frames written, 2 already there" in printed and "2 images under --out" in printed, error


def fake_network(calls):
    """A predictor whose logits of a frame depend on the other frames of its call (as batched
    convolutions may, by an ulp); ``calls`` collects the shape of every call's images."""

    def predict(images):
        calls.append(images.shape)
        x = jnp.asarray(images, jnp.float32) / 64
        return {"logits": jnp.concatenate([x, x[..., :1] * 0 + x.mean(axis=0, keepdims=True)[..., :1]], axis=-1)}

    return predict


def run_fake(tmp_path, name, paths, batch_size):
    from jaxanom.app.predict import PredictSettings, Scorer, predict_images

    calls = []
    settings = PredictSettings(methods=("msp",), batch_size=batch_size)
    predict_images(paths, tmp_path / name, Scorer(fake_network(calls), settings), progress=False)
    return calls, {p.stem: np.load(tmp_path / name / "npy" / "msp" / f"{p.stem}.npy") for p in paths}


def test_each_frame_is_scored_independently_of_its_batch(tmp_path):
    paths = write_images(tmp_path / "images", ["a.png", "b.png", "c.png", "d.png"], shape=(8, 12))
    _, alone = run_fake(tmp_path, "one", paths, 1)
    _, batched = run_fake(tmp_path, "three", paths, 3)
    for name in alone:
        np.testing.assert_array_equal(batched[name], alone[name], err_msg=name)


def test_a_batch_is_never_padded(tmp_path):
    paths = write_images(tmp_path / "images", ["a.png", "b.png", "c.png"], shape=(8, 12))
    calls, _ = run_fake(tmp_path, "maps", paths, 32)
    assert sum(shape[0] for shape in calls) == 3, calls


def test_device_out_of_memory_is_one_line_and_keeps_the_maps(tiny_run, tmp_path, capsys, monkeypatch):  # noqa: F811
    from jaxanom.app import evaluate

    real = evaluate.predictor

    def running_out(model, variables):  # the device runs out of memory on the third frame
        forward, calls = real(model, variables), []

        def predict(images):
            calls.append(len(images))
            if len(calls) == 3:
                raise jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 1.10GiB.")
            return forward(images)

        return predict

    monkeypatch.setattr(evaluate, "predictor", running_out)
    paths = write_images(tmp_path / "images", ["a.png", "b.png", "c.png", "d.png"])
    code, printed, error = predict(capsys, *paths, "--run", tiny_run, "--methods", "msp", "--out", tmp_path / "maps")
    assert code == 2 and len(error.splitlines()) == 1, error
    assert "out of memory" in error and "--batch-size" in error and "--size" in error, error
    assert sorted(p.name for p in (tmp_path / "maps" / "npy" / "msp").glob("*.npy")) == ["a.npy", "b.npy"]
