"""A user's mistake found deep in the library (a file read lazily, a config value checked when
the run starts) reaches the command line as one line naming its flag, exit status 2, with
nothing left in --out; a library bug keeps its traceback."""
import json
import shutil
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from converted_run import tiny_run  # noqa: F401  (the module fixture: a tiny converted run)
from jaxanom.cli import main

H, W = 6, 10
TRAIN = "from jaxanom.app.demos.sml_cudam import DemoConfig\nexperiment = DemoConfig.quick().experiment\n"


def _road_anomaly(root):
    """Two frames in Road Anomaly's official layout."""
    names = ["cows.jpg", "rock.jpg"]
    for k, name in enumerate(names):
        (root / "frames" / f"{name[:-4]}.labels").mkdir(parents=True)
        cv2.imwrite(str(root / "frames" / name), np.full((H, W, 3), 60 + 40 * k, np.uint8))
        cv2.imwrite(str(root / "frames" / f"{name[:-4]}.labels" / "labels_semantic.png"),
                    np.where(np.arange(H * W).reshape(H, W) % 3 == 0, 2, 0).astype(np.uint8))
    (root / "frame_list.json").write_text(json.dumps(names))
    return root


def _broken_frame_list(root):
    _road_anomaly(root)
    (root / "frame_list.json").write_text("[not json")
    return root


def _static_with_bad_overlay(root):
    """A Fishyscapes Static frame whose overlay is 3x3 while its Cityscapes image is H x W."""
    masks, cityscapes = root / "fs_val_v3", root / "cityscapes"
    (cityscapes / "leftImg8bit/val/lindau").mkdir(parents=True)
    masks.mkdir()
    cv2.imwrite(str(cityscapes / "leftImg8bit/val/lindau/lindau_000001_000019_leftImg8bit.png"),
                np.zeros((H, W, 3), np.uint8))
    cv2.imwrite(str(masks / "0003_lindau_000001_000019_labels.png"), np.zeros((H, W), np.uint8))
    np.savez(masks / "0003_lindau_000001_000019_rgb.npz", rgb=np.zeros((3, 3, 3), np.int16))
    return masks, cityscapes


def _maps_of_the_wrong_size(root):
    """Score maps as ``predict --format smiyc`` writes them, 5x5 for H x W frames."""
    for name in ("cows", "rock"):
        file = root / "anomaly_p" / "msp" / "RoadAnomaly" / f"{name}.hdf5"
        file.parent.mkdir(parents=True, exist_ok=True)
        with h5py.File(file, "w") as f:
            f["value"] = np.zeros((5, 5), np.float16)
    return root


def _three_class_stats(root):
    from jaxanom import sml

    sml.save_stats(root / "stats.npz", np.zeros(3), np.ones(3), np.full(3, 1e6))
    return str(root / "stats.npz")


def _checkpoint_of_other_keys(root):
    import torch

    torch.save({"conv.weight": torch.zeros(2, 3, 1, 1)}, root / "other.pth")
    return str(root / "other.pth")


def _deepscene(root):
    """Two frames of DeepScene's train split (its colour-coded labels all 'road')."""
    for k in range(2):
        (root / "train" / "rgb").mkdir(parents=True, exist_ok=True)
        (root / "train" / "GT_color").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / "train" / "rgb" / f"b{k}-0{k}517_Clipped.jpg"), np.zeros((H, W, 3), np.uint8))
        cv2.imwrite(str(root / "train" / "GT_color" / f"b{k}-0{k}517_mask.png"), np.full((H, W, 3), 170, np.uint8))
    return str(root)


def _mmf_folder_without_networks(root):
    """A folder with the results.json of ``jaxanom demo mmf`` and none of its trained networks."""
    root.mkdir()
    shutil.copy(Path(__file__).parents[1] / "fixtures" / "configs" / "mmf_results.json", root / "results.json")
    return str(root)


def _cityscapes_frame(root):
    """One training frame in Cityscapes' layout (no labels: fit-stats reads none)."""
    (root / "leftImg8bit/train/city").mkdir(parents=True)
    image = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    cv2.imwrite(str(root / "leftImg8bit/train/city/city_000000_000000_leftImg8bit.png"), image)
    return str(root)


def _train_config(root):
    (root / "exp.py").write_text(TRAIN)
    return str(root / "exp.py")


def _smiyc(root, label: int, size=(H, W)):
    """Two frames in SegmentMeIfYouCan's layout whose labels are all ``label``."""
    for folder in ("images", "labels_masks"):
        (root / folder).mkdir(parents=True)
    for name in ("f0", "f1"):
        cv2.imwrite(str(root / "images" / f"{name}.png"), np.full((*size, 3), 90, np.uint8))
        cv2.imwrite(str(root / "labels_masks" / f"{name}_labels_semantic.png"), np.full(size, label, np.uint8))
    return str(root)


def _array(path, values):
    np.save(path, values)
    return str(path)


def _evaluate_smiyc(run, path, *flags):
    return ["evaluate", "--run", str(run), "--dataset", "smiyc", "--path", path, "--methods", "msp", *flags]


OUT = "<out>"  # where a case names its output itself; the others get --out <out>
# each case: (the command's arguments, a text the line holds (the flag or the file named))
CASES = {
    "evaluate: overlay of another size": lambda tmp, run: (
        ["evaluate", "--run", str(run), "--dataset", "fishyscapes-static", "--methods", "msp",
         "--path", str(_static_with_bad_overlay(tmp)[0]), "--base", str(tmp / "cityscapes")],
        "overlay: shape (3, 3, 3) of "),
    "evaluate: saved maps of another size": lambda tmp, run: (
        ["evaluate", "--maps", str(_maps_of_the_wrong_size(tmp / "maps")), "--dataset", "road-anomaly",
         "--path", str(_road_anomaly(tmp / "ra"))], "--maps: "),
    "evaluate: a broken frame list": lambda tmp, run: (
        ["evaluate", "--run", str(run), "--dataset", "road-anomaly", "--methods", "msp",
         "--path", str(_broken_frame_list(tmp / "ra"))], "--path "),
    "evaluate: statistics of another class count": lambda tmp, run: (
        ["evaluate", "--run", str(run), "--dataset", "road-anomaly", "--methods", "sml",
         "--stats", _three_class_stats(tmp), "--path", str(_road_anomaly(tmp / "ra"))], "--stats "),
    "evaluate: frames without an anomaly pixel": lambda tmp, run: (
        _evaluate_smiyc(run, _smiyc(tmp / "d", 0), "--track", "anomaly"),
        "error: --path: no anomaly pixel in any of the 2 frames scored (f0: no anomaly pixel; f1: no anomaly pixel)"),
    "evaluate: frames without an anomaly pixel, smiyc convention": lambda tmp, run: (
        _evaluate_smiyc(run, _smiyc(tmp / "d", 0), "--track", "anomaly", "--convention", "smiyc"),
        "--path: no anomaly pixel in any of the 2 frames"),
    "evaluate: all-void frames, no track": lambda tmp, run: (
        _evaluate_smiyc(run, _smiyc(tmp / "d", 255), "--track", "none"), "(f0: all void; f1: all void)"),
    "evaluate: every frame skipped by the protocol": lambda tmp, run: (
        _evaluate_smiyc(run, _smiyc(tmp / "d", 0), "--track", "anomaly", "--protocol", "erfnet-community"),
        "--path: no frame to score; the erfnet-community protocol skipped 2 frames without anomaly pixels (f0, f1)"),
    "evaluate: smiyc without its track": lambda tmp, run: (
        _evaluate_smiyc(run, _smiyc(tmp / "d", 0)), "error: --track: the smiyc dataset holds either track"),
    "score: labels without an anomaly pixel": lambda tmp, run: (
        ["score", "--logits", _array(tmp / "logits.npy", np.ones((2, 3, 4, 5), np.float32)), "--labels",
         _array(tmp / "labels.npy", np.zeros((2, 4, 5), np.uint8)), "--methods", "msp"],
        f"error: --labels {tmp / 'labels.npy'}: no anomaly (1) pixel outside void (255) in any of its 2 images; AP, "
        "AUROC and FPR@95 need both classes (leave --labels out for the score maps alone)"),
    "evaluate: an MMF folder without its networks": lambda tmp, run: (
        ["evaluate", "--mmf", _mmf_folder_without_networks(tmp / "mmf"), "--dataset", "synthetic", "--path", "anomaly",
         "--frames", "1"], "--mmf "),
    "fit-stats: frames too small to pool": lambda tmp, run: (
        ["fit-stats", "--run", str(run), "--frames", "1", "--size", "3x3", "--policy", "shrink",
         "--cityscapes", _cityscapes_frame(tmp / "cs"), "--out", f"{OUT}/stats.npz"],
        "stats has only 9 counted pixel(s)"),
    "fit-stats: a converted run without frames": lambda tmp, run: (
        ["fit-stats", "--run", str(run), "--frames", "2", "--missing", "pooled", "--out", f"{OUT}/stats.npz"],
        "--cityscapes DIR needed"),
    "convert-weights: a checkpoint of another network": lambda tmp, run: (
        ["convert-weights", "--from", "erfnet-cityscapes", _checkpoint_of_other_keys(tmp), OUT],
        "IN: state dict does not match erfnet-cityscapes"),
    "convert-weights: an output stride for ESPNet": lambda tmp, run: (
        ["convert-weights", "--from", "espnet-cityscapes", _checkpoint_of_other_keys(tmp), OUT, "--output-stride", "8"],
        "error: --output-stride: espnet-cityscapes is no DeepLabV3+ and has no output stride to set; got 8"),
    "train: warm-up longer than the run": lambda tmp, run: (
        ["train", "--config", _train_config(tmp), "--set", "train.optim.warmup_steps=50", "--no-progress"],
        "warmup_steps=50"),
    "train: init-modules the network lacks": lambda tmp, run: (
        ["train", "--config", _train_config(tmp), "--init-from", str(run), "--init-modules", "nope",
         "--no-progress"],
        "--init-from "),
    "demo offroad: a source starting past its frames": lambda tmp, run: (
        ["demo", "offroad", "--quick", "--set", "active.reader=deepscene", "--set", f"active.root={_deepscene(tmp)}",
         "--set", "active.start=5", "--no-progress"], "active: deepscene source in "),
    "demo: --steps within its warm-up": lambda tmp, run: (
        ["demo", "--steps", "5", "--no-progress"], "experiment: steps: "),
    "demo mmf: --steps within the segmenter's warm-up": lambda tmp, run: (
        ["demo", "mmf", "--steps", "5", "--no-progress"], "pipeline.segmenter: steps: "),
    "demo: an attention its objective does not train": lambda tmp, run: (
        ["demo", "--quick", "--set", "experiment.attention=msaam", "--no-progress"], "experiment: attention and "),
}


@pytest.mark.parametrize("case", CASES)
def test_a_user_mistake_is_one_line_naming_it_and_writes_nothing(case, tiny_run, tmp_path, capsys):  # noqa: F811
    argv, named = CASES[case](tmp_path, tiny_run)
    out = tmp_path / "out"
    out.mkdir()  # the user's empty folder stays, so what a command leaves in it shows
    argv = [a.replace(OUT, str(out)) for a in argv] if any(OUT in a for a in argv) else [*argv, "--out", str(out)]
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"jaxanom {argv[0]}: error: "), lines
    assert named in lines[0], lines
    assert list(out.iterdir()) == []


def test_resuming_a_damaged_checkpoint_is_one_line_naming_out_and_changes_nothing(tiny_run, tmp_path,  # noqa: F811
                                                                                   capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    for path in (run / "checkpoints").rglob("*"):  # every file: damaged arrays alone leave orbax's reads pending
        if path.is_file():
            path.write_bytes(b"\x00garbage")
    before = {path: path.read_bytes() for path in run.rglob("*") if path.is_file()}
    assert main(["train", "--resume", "--out", str(run), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"jaxanom train: error: --out {run}: checkpoint directory "), lines
    assert "step 0 cannot be read" in lines[0]
    assert {path: path.read_bytes() for path in run.rglob("*") if path.is_file()} == before


def test_a_library_bug_while_reading_a_dataset_keeps_its_traceback(tiny_run, tmp_path, monkeypatch):  # noqa: F811
    from jaxanom.data import RoadAnomaly

    def broken(self, index):
        raise ValueError("a bug of ours")

    monkeypatch.setattr(RoadAnomaly, "__getitem__", broken)
    with pytest.raises(ValueError, match="a bug of ours"):
        main(["evaluate", "--run", str(tiny_run), "--dataset", "road-anomaly", "--methods", "msp",
              "--path", str(_road_anomaly(tmp_path / "ra")), "--out", str(tmp_path / "out")])


@pytest.fixture(scope="module")
def espnet_run(tmp_path_factory):
    """An ESPNet run (constant weights): a network that takes sizes in multiples of 8 only."""
    import jax

    from jaxanom.app.runs import write_run
    from jaxanom.models import build_model

    model = build_model("espnet_p2_q8", num_classes=19)
    shapes = jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), np.zeros((1, 32, 32, 3)))
    folder = tmp_path_factory.mktemp("espnet") / "run"
    write_run(folder, "espnet_p2_q8", model, jax.tree_util.tree_map(lambda l: np.full(l.shape, 0.01, l.dtype), shapes))
    return folder


def _image(root, height, width):
    root.mkdir()
    cv2.imwrite(str(root / "odd.png"), np.zeros((height, width, 3), np.uint8))
    return str(root / "odd.png")


SIZE_CASES = {  # sizes the network does not take: one line naming the flag, as predict's
    "evaluate: 1x1 frames": lambda tmp, run: (
        _evaluate_smiyc(run, _smiyc(tmp / "d", 1, (1, 1)), "--track", "anomaly"),
        "error: --path: the network does not run on 1x1 images (f0): images: expected H and W multiples of 8"),
    "fit-stats: --size 1x1": lambda tmp, run: (
        ["fit-stats", "--run", str(run), "--frames", "1", "--size", "1x1", "--cityscapes",
         _cityscapes_frame(tmp / "cs"), "--out", f"{OUT}/stats.npz"],
        "error: --size: the network does not run on 1x1 images (the working size)"),
    "predict: a 33x65 image": lambda tmp, run: (
        ["predict", _image(tmp / "images", 33, 65), "--run", str(run), "--methods", "msp"],
        "error: --size: the network does not run on 33x65 images (odd): "),
}


@pytest.mark.parametrize("case", SIZE_CASES)
def test_a_size_the_network_does_not_take_is_one_line_naming_the_flag(case, espnet_run, tmp_path, capsys):
    argv, named = SIZE_CASES[case](tmp_path, espnet_run)
    out = tmp_path / "out"
    out.mkdir()
    argv = [a.replace(OUT, str(out)) for a in argv] if any(OUT in a for a in argv) else [*argv, "--out", str(out)]
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and named in lines[0], lines
    assert [p.name for p in out.iterdir()] == (["settings.json"] if argv[0] == "predict" else [])  # predict resumes


def _huge_logits(model, variables):
    """A stand-in for ``app.evaluate.predictor``: logits 1e5, and 2e5 on the left half, at any size."""
    def call(images):
        logits = np.zeros((*images.shape[:3], 19), np.float32)
        logits[..., 0], logits[:, :, :images.shape[2] // 2, 1] = 1e5, 2e5
        return {"logits": logits}
    return call


def _one_anomalous_frame(tmp_path):
    """_smiyc's frames, f1 with anomaly pixels in its top rows."""
    path = _smiyc(tmp_path / "d", 0)
    cv2.imwrite(str(tmp_path / "d" / "labels_masks" / "f1_labels_semantic.png"),
                np.where(np.arange(H)[:, None] < 2, 1, 0).repeat(W, 1).astype(np.uint8))
    return path


def test_scores_the_kit_cannot_store_are_one_line_naming_the_method(tiny_run, tmp_path, capsys,  # noqa: F811
                                                                      monkeypatch):
    """The official kit casts maps to float16: a max_logit of -2e5 has no kit number (inf there)."""
    import jaxanom.app.evaluate

    monkeypatch.setattr(jaxanom.app.evaluate, "predictor", _huge_logits)
    path = _one_anomalous_frame(tmp_path)
    argv = _evaluate_smiyc(tiny_run, path, "--methods", "msp,max_logit", "--track", "anomaly")
    assert main([*argv, "--convention", "smiyc", "--out", str(tmp_path / "o")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == ["jaxanom evaluate: error: --methods: max_logit's scores of frame f0 reach -200000, outside "
                     "float16's range (|score| <= 65504); the official SegmentMeIfYouCan kit stores maps as float16, "
                     "where such scores become inf and its bins undefined; use --convention exact"]
    assert not (tmp_path / "o").exists()
    assert main([*argv, "--out", str(tmp_path / "o")]) == 0  # the exact curves take any float


def test_the_frames_a_protocol_skips_are_named(tiny_run, tmp_path, capsys, monkeypatch):  # noqa: F811
    import jaxanom.app.evaluate

    monkeypatch.setattr(jaxanom.app.evaluate, "predictor", _huge_logits)
    argv = _evaluate_smiyc(tiny_run, _one_anomalous_frame(tmp_path), "--track", "none", "--protocol",
                           "erfnet-community", "--out", str(tmp_path / "o"))
    assert main(argv) == 0
    assert ("jaxanom evaluate: the erfnet-community protocol skipped 1 of 2 frames, which have no anomaly pixel: f0 "
            "(metrics.json: frames_skipped)") in capsys.readouterr().out
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["frames_skipped"] == ["f0"]
