"""A tiny converted run: the module fixture of the tests of commands that read a run folder; and tiny
Cityscapes frames, which a converted run's statistics are fitted on."""
from pathlib import Path

import cv2
import jax
import numpy as np
import pytest

from jaxanom.app.runs import write_run
from jaxanom.models import build_model

SIZE = (48, 96)  # the network's working size in these tests


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A DeepLabV3+ tiny run folder (19 classes) written as convert-weights writes one."""
    return write_tiny_run(tmp_path_factory.mktemp("tiny") / "run", 19)


def write_tiny_run(folder, classes: int):
    """``folder``: a DeepLabV3+ tiny run of ``classes`` outputs written as convert-weights writes one
    (20: the 19 trainIds and a void output, as the ESPNet and ERFNet authors' weights)."""
    model = build_model("deeplabv3plus_tiny", num_classes=classes, attention=None, output_stride=16)
    shapes = jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), np.zeros((1, 32, 32, 3)))
    rng = np.random.default_rng(0)

    def fill(path, leaf):
        name = path[-1].key
        if name in ("scale", "var"):
            return np.ones(leaf.shape, np.float32)
        if name in ("bias", "mean"):
            return np.zeros(leaf.shape, np.float32)
        return (rng.normal(size=leaf.shape) * np.sqrt(2 / np.prod(leaf.shape[:-1]))).astype(np.float32)

    write_run(folder, "deeplabv3plus_tiny", model, jax.tree_util.tree_map_with_path(fill, shapes))
    return folder


def write_tiny_cityscapes(root: Path, sizes, labels: bool = False) -> Path:
    """Random frames of ``sizes`` (H, W) in the Cityscapes layout (train split, one city) under ``root``;
    with ``labels``, label images of one class (road)."""
    rng = np.random.default_rng(2)
    for index, (height, width) in enumerate(sizes):
        name = f"city_000000_00000{index}"
        path = root / "leftImg8bit" / "train" / "city" / f"{name}_leftImg8bit.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), rng.integers(0, 256, (height, width, 3), dtype=np.uint8))
        if labels:
            label = root / "gtFine" / "train" / "city" / f"{name}_gtFine_labelIds.png"
            label.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(label), np.full((height, width), 7, np.uint8))
    return root
