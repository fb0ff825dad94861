"""DeepScene / Freiburg Forest and RUGD readers on fixtures in the official layouts."""
import cv2
import numpy as np
import pytest

from jaxanom.data.deepscene import DeepScene
from jaxanom.data.rugd import RUGD

DS_COLOURS = [(170, 170, 170), (0, 255, 0), (102, 102, 51), (0, 120, 255), (0, 0, 0)]


def _write(path, rgb):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.ascontiguousarray(np.asarray(rgb, np.uint8)[..., ::-1]))


def _deepscene(root, split="train", count=2):
    rng = np.random.default_rng(0)
    truth = {}
    for i in range(count):
        ids = rng.integers(0, 5, (6, 9))
        ids[0, 0] = 255
        colour = np.array([DS_COLOURS[k] if k < 5 else (255, 255, 255) for k in ids.ravel()]).reshape(6, 9, 3)
        colour[1, 1] = (0, 60, 0)  # the tree colour of some releases: vegetation
        ids[1, 1] = 2
        stem = f"b{i}-0{i}517"
        _write(root / split / "rgb" / f"{stem}_Clipped.jpg", rng.integers(0, 255, (6, 9, 3)))
        _write(root / split / "GT_color" / f"{stem}_mask.png", colour)
        truth[stem] = ids
    return truth


def test_deepscene_decodes_colour_labels_and_pairs_files_by_stem(tmp_path):
    truth = _deepscene(tmp_path)
    reader = DeepScene(tmp_path, "train")
    assert len(reader) == 2
    for i in range(2):
        frame = reader[i]
        assert frame["image"].shape == (6, 9, 3) and frame["image"].dtype == np.uint8
        np.testing.assert_array_equal(frame["label"], truth[frame["name"]])


def test_deepscene_bad_folders_files_and_colours(tmp_path):
    with pytest.raises(FileNotFoundError, match="DeepScene images"):
        DeepScene(tmp_path, "train")
    with pytest.raises(ValueError, match="split"):
        DeepScene(tmp_path, "val")
    _deepscene(tmp_path)
    (tmp_path / "train" / "GT_color" / "b1-01517_mask.png").unlink()
    with pytest.raises(FileNotFoundError, match="b1-01517"):
        DeepScene(tmp_path, "train")
    _write(tmp_path / "train" / "GT_color" / "b1-01517_mask.png", np.full((6, 9, 3), (200, 30, 200)))
    with pytest.raises(ValueError, match="match no class colour"):
        DeepScene(tmp_path, "train")[1]


RUGD_MAP = "0 void 0 0 0\n1 dirt 108 64 20\n2 sand 255 229 204\n3 grass 0 102 0\n4 tree 0 255 0\n"
RUGD_COLOURS = {0: (0, 0, 0), 1: (108, 64, 20), 2: (255, 229, 204), 3: (0, 102, 0), 4: (0, 255, 0)}


def _rugd(root, sequence="park-2", numbers=(1901, 5, 10)):
    (root / "RUGD_annotations").mkdir(parents=True, exist_ok=True)
    (root / "RUGD_annotations" / "RUGD_annotation-colormap.txt").write_text(RUGD_MAP)
    rng = np.random.default_rng(1)
    truth = {}
    for n in numbers:
        ids = rng.integers(0, 5, (5, 7))
        colour = np.array([RUGD_COLOURS[k] for k in ids.ravel()]).reshape(5, 7, 3)
        name = f"{sequence}_{n:05d}"  # the real names, e.g. park-2/park-2_01901.png
        _write(root / "RUGD_frames-with-annotations" / sequence / f"{name}.png", rng.integers(0, 255, (5, 7, 3)))
        _write(root / "RUGD_annotations" / sequence / f"{name}.png", colour)
        truth[name] = np.where(ids == 0, 255, ids)
    return truth


def test_rugd_frames_come_in_video_order_with_colour_map_ids(tmp_path):
    truth = _rugd(tmp_path)
    reader = RUGD(tmp_path, "park-2")
    assert [reader[i]["name"] for i in range(3)] == ["park-2_00005", "park-2_00010", "park-2_01901"]
    assert reader.class_names == ("void", "dirt", "sand", "grass", "tree")
    for i in range(3):
        frame = reader[i]
        np.testing.assert_array_equal(frame["label"], truth[frame["name"]])
        np.testing.assert_array_equal(frame["image"], cv2.imread(str(tmp_path / "RUGD_frames-with-annotations" / "park-2" / f"{frame['name']}.png"))[..., ::-1])


def test_rugd_bad_folders_and_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="RUGD frames of 'creek'"):
        RUGD(tmp_path, "creek")
    _rugd(tmp_path)
    (tmp_path / "RUGD_annotations" / "park-2" / "park-2_00010.png").unlink()
    with pytest.raises(FileNotFoundError, match="park-2_00010"):
        RUGD(tmp_path, "park-2")
    _rugd(tmp_path)
    (tmp_path / "RUGD_annotations" / "RUGD_annotation-colormap.txt").write_text("0 void zero 0 0\n")
    with pytest.raises(ValueError, match="line 1"):
        RUGD(tmp_path, "park-2")
    (tmp_path / "RUGD_annotations" / "RUGD_annotation-colormap.txt").unlink()
    with pytest.raises(FileNotFoundError, match="colour map"):
        RUGD(tmp_path, "park-2")
