"""``fit-stats --cityscapes DIR --size HxW``: statistics of a converted network on real Cityscapes frames."""
import cv2
import jax
import numpy as np
import pytest

from conftest import REALDATA
from jaxanom.cli import main
from jaxanom.data import Cityscapes
from jaxanom.data.frames import Resized
from jaxanom.data.transforms import normalize
from jaxanom.models import build_model
from jaxanom.sml import load_stats
from converted_run import tiny_run  # noqa: F401  (a module-scoped fixture: a converted tiny DeepLabV3+)

CITYSCAPES8 = REALDATA / "cityscapes8"


@pytest.fixture(scope="module")
def cityscapes8():
    if not (CITYSCAPES8 / "leftImg8bit" / "train").is_dir():
        pytest.skip(f"real Cityscapes frames not found at {CITYSCAPES8} (set JAXANOM_REALDATA)")
    return CITYSCAPES8


def test_resized_frames_are_bilinear_images_and_nearest_labels(cityscapes8):
    frame = Cityscapes(cityscapes8, "train")[0]
    small = Resized(Cityscapes(cityscapes8, "train"), 40, 72)[0]
    assert small["image"].shape == (40, 72, 3) and small["label"].shape == (40, 72)
    # labels by nearest neighbour: no value that the source label does not have (bilinear would blend ids)
    assert set(np.unique(small["label"])) <= set(np.unique(frame["label"]))
    np.testing.assert_array_equal(small["image"], cv2.resize(frame["image"], (72, 40), interpolation=cv2.INTER_LINEAR))
    with pytest.raises(ValueError, match="height, width"):
        Resized(Cityscapes(cityscapes8, "train"), 0, 8)


def test_fit_stats_on_real_cityscapes_frames_at_a_working_size(cityscapes8, tiny_run, tmp_path):  # noqa: F811
    out = tmp_path / "stats.npz"
    assert main(["fit-stats", "--run", str(tiny_run), "--cityscapes", str(cityscapes8), "--size", "32x64",
                 "--frames", "2", "--policy", "none", "--missing", "pooled", "--out", str(out)]) == 0
    mean, std, counts = load_stats(out)
    # reference: the two frames resized by OpenCV, the network's logits, per-class max-logit moments in NumPy
    from jaxanom.app.experiment import load_variables

    _, variables = load_variables(tiny_run)
    model = build_model("deeplabv3plus_tiny", num_classes=19, attention=None, output_stride=16)
    reader = Cityscapes(cityscapes8, "train")
    images = np.stack([cv2.resize(reader[i]["image"], (64, 32), interpolation=cv2.INTER_LINEAR) for i in range(2)])
    logits = np.asarray(jax.jit(lambda x: model.apply(variables, normalize(x), train=False)["logits"])(images),
                        np.float64).reshape(-1, 19)
    predicted, value = logits.argmax(-1), logits.max(-1)
    want_counts = np.bincount(predicted, minlength=19)
    np.testing.assert_array_equal(counts, want_counts)
    for c in range(19):
        v = value[predicted == c]
        if len(v) >= 2 and v.std() > 0:
            np.testing.assert_allclose([mean[c], std[c]], [v.mean(), v.std(ddof=1)], rtol=1e-4)
        else:  # pooled
            np.testing.assert_allclose([mean[c], std[c]], [value.mean(), value.std(ddof=1)], rtol=1e-4)


def test_fit_stats_size_must_be_h_by_w(cityscapes8, tiny_run, tmp_path, capsys):  # noqa: F811
    code = main(["fit-stats", "--run", str(tiny_run), "--cityscapes", str(cityscapes8), "--size", "32by64",
                 "--out", str(tmp_path / "s.npz")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "--size" in error and len(error.splitlines()) == 1 and not list(tmp_path.iterdir())
