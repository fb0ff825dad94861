"""``evaluate --dataset camvid``: a run's mIoU over CamVid's 11 classes (void ignored) on a split of the
tiny fixture in CamVid's real layout, against a NumPy confusion matrix of the network's argmax."""
import json

import cv2
import numpy as np
import pytest

from camvid_tree import write_camvid
from converted_run import write_tiny_run
from jaxanom.app.experiment import build_network, load_variables
from jaxanom.cli import main
from jaxanom.data.transforms import normalize


@pytest.fixture(scope="module")
def camvid_and_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("camvid")
    written = write_camvid(root / "CamVid", 32, 48)
    return root / "CamVid", write_tiny_run(root / "run", 11), written


def _reference(run, frames) -> tuple[float, float, list]:
    """mIoU, pixel accuracy and per-class IoU from the equations: labels read with OpenCV (11 is void),
    the network's argmax computed by its own ``apply``, one (11, 11) matrix summed with NumPy."""
    experiment, variables = load_variables(run)
    model = build_network(experiment)
    matrix = np.zeros((11, 11), np.int64)
    for _, image, label in frames:
        logits = np.asarray(model.apply(variables, normalize(image[None]), train=False)["logits"][0])
        keep = label != 11
        np.add.at(matrix, (label[keep].astype(np.int64), logits.argmax(-1)[keep]), 1)
    tp = np.diag(matrix).astype(np.float64)
    union = matrix.sum(0) + matrix.sum(1) - tp
    iou = [tp[k] / union[k] if union[k] else None for k in range(11)]
    return float(np.mean([v for v in iou if v is not None])), float(tp.sum() / matrix.sum()), iou


@pytest.mark.parametrize("split", ["test", "train"])
def test_camvid_miou_against_a_numpy_confusion_matrix(camvid_and_run, tmp_path, split, capsys):
    root, run, written = camvid_and_run
    more = [] if split == "test" else ["--split", split]  # test is the default
    assert main(["evaluate", "--run", str(run), "--dataset", "camvid", "--path", str(root), *more,
                 "--out", str(tmp_path / "out")]) == 0
    record = json.loads((tmp_path / "out" / "metrics.json").read_text())
    miou, accuracy, iou = _reference(run, [(n, i, cv2.imread(str(root / f"{split}annot" / f"{n}.png"), 0))
                                           for n, i, _ in written[split]])
    assert (record["split"], record["frames"]) == (split, len(written[split]))
    assert record["metrics"]["miou"] == pytest.approx(miou, abs=1e-12)
    assert record["metrics"]["pixel_accuracy"] == pytest.approx(accuracy, abs=1e-12)
    assert record["metrics"]["classes"] == ["sky", "building", "pole", "road", "pavement", "tree", "sign symbol",
                                              "fence", "car", "pedestrian", "bicyclist"]
    assert record["metrics"]["iou"] == pytest.approx(iou, abs=1e-12)
    assert f"mIoU {100 * miou:.2f}%" in capsys.readouterr().out


@pytest.mark.parametrize("args, flag", [
    (["--dataset", "camvid", "--stats", "x.npz"], "--stats"),
    (["--dataset", "camvid", "--protocol", "erfnet-community"], "--protocol"),
    (["--dataset", "camvid", "--evaluators", "pixel"], "--evaluators"),
    (["--dataset", "smiyc", "--track", "anomaly", "--split", "test"], "--split"),
])
def test_options_of_the_other_kind_of_dataset_are_refused(camvid_and_run, tmp_path, capsys, args, flag):
    root, run, _ = camvid_and_run
    assert main(["evaluate", "--run", str(run), "--path", str(root), *args, "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"jaxanom evaluate: error: {flag}") and len(error.splitlines()) == 1, error
    assert not (tmp_path / "out").exists()


def test_a_run_of_other_classes_is_refused_naming_the_run(camvid_and_run, tmp_path, capsys):
    root, _, _ = camvid_and_run
    run = write_tiny_run(tmp_path / "run19", 19)
    assert main(["evaluate", "--run", str(run), "--dataset", "camvid", "--path", str(root),
                 "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("jaxanom evaluate: error: --run") and "19 outputs" in error, error
