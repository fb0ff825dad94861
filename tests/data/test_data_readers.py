"""Dataset readers on tiny fixtures in each official layout, on bad folders, and on real frames."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from jaxanom.data import (Cityscapes, FishyscapesLostAndFound, FishyscapesStatic, RoadAnomaly,
                          SegmentMeIfYouCan)

H, W = 6, 10


def _write_rgb(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), rgb[..., ::-1])


def _write_label(path: Path, label: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), label.astype(np.uint8))


def _image(seed):
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _anomaly_label(seed):
    return np.random.default_rng(seed).choice(np.array([0, 1, 255], np.uint8), (H, W))


# ----------------------------------------------------------------------------- Cityscapes

# labelId -> trainId, from the official table (independent of the module's copy).
OFFICIAL = {7: 0, 8: 1, 11: 2, 12: 3, 13: 4, 17: 5, 19: 6, 20: 7, 21: 8, 22: 9, 23: 10, 24: 11,
            25: 12, 26: 13, 27: 14, 28: 15, 31: 16, 32: 17, 33: 18}


def _cityscapes(root: Path):
    frames = {}
    for k, (city, frame_id) in enumerate([("aachen", "aachen_000000_000019"), ("bremen", "bremen_000003_000019")]):
        image = _image(k)
        label_ids = np.random.default_rng(10 + k).integers(0, 34, (H, W)).astype(np.uint8)
        _write_rgb(root / "leftImg8bit" / "val" / city / f"{frame_id}_leftImg8bit.png", image)
        _write_label(root / "gtFine" / "val" / city / f"{frame_id}_gtFine_labelIds.png", label_ids)
        frames[frame_id] = (image, label_ids)
    return frames


def test_cityscapes_reads_images_and_maps_label_ids_to_train_ids(tmp_path):
    frames = _cityscapes(tmp_path)
    reader = Cityscapes(tmp_path, "val")
    assert len(reader) == 2
    for i in range(2):
        item = reader[i]
        image, label_ids = frames[item["name"]]
        np.testing.assert_array_equal(item["image"], image)
        expected = np.vectorize(lambda v: OFFICIAL.get(int(v), 255))(label_ids).astype(np.uint8)
        np.testing.assert_array_equal(item["label"], expected)
        assert item["label"].dtype == np.uint8


def test_cityscapes_errors_name_the_missing_folder_or_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="leftImg8bit/val"):
        Cityscapes(tmp_path, "val")
    _cityscapes(tmp_path)
    with pytest.raises(FileNotFoundError, match="leftImg8bit/train"):
        Cityscapes(tmp_path, "train")
    (tmp_path / "gtFine/val/bremen/bremen_000003_000019_gtFine_labelIds.png").unlink()
    with pytest.raises(FileNotFoundError, match="bremen_000003_000019_gtFine_labelIds.png"):
        Cityscapes(tmp_path, "val")


def test_cityscapes_rejects_corrupt_images_and_unknown_label_ids(tmp_path):
    _cityscapes(tmp_path)
    bad_image = tmp_path / "leftImg8bit/val/aachen/aachen_000000_000019_leftImg8bit.png"
    bad_image.write_bytes(b"not a png at all")
    reader = Cityscapes(tmp_path, "val")
    with pytest.raises(ValueError, match="cannot decode .*aachen_000000_000019_leftImg8bit.png"):
        reader[0]
    label = np.full((H, W), 7, np.uint8)
    label[0, 0] = 40
    _write_label(tmp_path / "gtFine/val/bremen/bremen_000003_000019_gtFine_labelIds.png", label)
    with pytest.raises(ValueError, match=r"bremen_000003_000019_gtFine_labelIds.png, got \[40\]"):
        reader[1]


# ----------------------------------------------------------------------------- Fishyscapes

def _lost_and_found(tmp_path):
    masks, laf = tmp_path / "fishyscapes_lostandfound", tmp_path / "LostAndFound"
    expected = {}
    layout = [("test", "04_Maurener_Weg_8", "04_Maurener_Weg_8_000000_000030"),
              ("train", "01_Hanns_Klemm_Str_45", "01_Hanns_Klemm_Str_45_000002_000100")]
    for k, (split, city, laf_id) in enumerate(layout):
        image, label = _image(k), _anomaly_label(k)
        _write_rgb(laf / "leftImg8bit" / split / city / f"{laf_id}_leftImg8bit.png", image)
        _write_label(masks / f"{k:04d}_{laf_id}_labels.png", label)
        expected[f"{k:04d}"] = (image, label)
    return masks, laf, expected


def test_fishyscapes_lost_and_found_pairs_masks_with_lost_and_found_images(tmp_path):
    masks, laf, expected = _lost_and_found(tmp_path)
    reader = FishyscapesLostAndFound(masks, laf)
    assert len(reader) == 2
    for i in range(2):
        item = reader[i]
        np.testing.assert_array_equal(item["image"], expected[item["name"]][0])
        np.testing.assert_array_equal(item["label"], expected[item["name"]][1])


def test_fishyscapes_lost_and_found_errors(tmp_path):
    masks, laf, _ = _lost_and_found(tmp_path)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        FishyscapesLostAndFound(tmp_path / "nowhere", laf)
    (laf / "leftImg8bit/train/01_Hanns_Klemm_Str_45/01_Hanns_Klemm_Str_45_000002_000100_leftImg8bit.png").unlink()
    with pytest.raises(FileNotFoundError, match="01_Hanns_Klemm_Str_45_000002_000100_leftImg8bit.png"):
        FishyscapesLostAndFound(masks, laf)
    (masks / "0001_01_Hanns_Klemm_Str_45_000002_000100_labels.png").unlink()
    label = np.zeros((H, W), np.uint8)
    label[2, 3] = 2
    _write_label(masks / "0000_04_Maurener_Weg_8_000000_000030_labels.png", label)
    with pytest.raises(ValueError, match=r"0000_04_Maurener_Weg_8_000000_000030_labels.png, got \[2\]"):
        FishyscapesLostAndFound(masks, laf)[0]


def _static(tmp_path):
    masks, cityscapes = tmp_path / "fs_val_v3", tmp_path / "cityscapes"
    image, label = _image(5), _anomaly_label(5)
    overlay = np.random.default_rng(6).integers(-300, 300, (H, W, 3))
    _write_rgb(cityscapes / "leftImg8bit/val/lindau/lindau_000001_000019_leftImg8bit.png", image)
    _write_label(masks / "0003_lindau_000001_000019_labels.png", label)
    masks.mkdir(parents=True, exist_ok=True)
    np.savez(masks / "0003_lindau_000001_000019_rgb.npz", rgb=overlay)
    return masks, cityscapes, image, label, overlay


def test_fishyscapes_static_adds_the_overlay_to_the_cityscapes_image(tmp_path):
    masks, cityscapes, image, label, overlay = _static(tmp_path)
    item = FishyscapesStatic(masks, cityscapes)[0]
    expected = np.minimum(np.maximum(image.astype(np.int64) + overlay, 0), 255).astype(np.uint8)
    np.testing.assert_array_equal(item["image"], expected)
    np.testing.assert_array_equal(item["label"], label)
    assert item["name"] == "0003"


def test_fishyscapes_static_errors(tmp_path):
    masks, cityscapes, *_ = _static(tmp_path)
    (masks / "0003_lindau_000001_000019_rgb.npz").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="0003_lindau_000001_000019_rgb.npz"):
        FishyscapesStatic(masks, cityscapes)[0]
    (masks / "0003_lindau_000001_000019_rgb.npz").unlink()
    with pytest.raises(FileNotFoundError, match=r"0003_\*rgb.npz"):
        FishyscapesStatic(masks, cityscapes)
    with pytest.raises(FileNotFoundError, match="leftImg8bit"):
        FishyscapesStatic(masks, tmp_path / "no_cityscapes")


# ----------------------------------------------------------------------------- Road Anomaly

def _road_anomaly(root: Path):
    names, expected = ["cows.jpg", "rock.jpg"], {}
    for k, name in enumerate(names):
        image = np.full((H, W, 3), 40 * k + 60, np.uint8)  # flat colour: survives JPEG exactly
        raw = np.where(np.random.default_rng(k).random((H, W)) < 0.3, 2, 0).astype(np.uint8)
        _write_rgb(root / "frames" / name, image)
        _write_label(root / "frames" / f"{Path(name).stem}.labels" / "labels_semantic.png", raw)
        expected[Path(name).stem] = (image, (raw == 2).astype(np.uint8))
    (root / "frame_list.json").write_text(json.dumps(names))
    return expected


def test_road_anomaly_maps_label_2_to_anomaly(tmp_path):
    expected = _road_anomaly(tmp_path)
    reader = RoadAnomaly(tmp_path)
    assert len(reader) == 2
    for i in range(2):
        item = reader[i]
        image, label = expected[item["name"]]
        assert np.abs(item["image"].astype(int) - image).max() <= 2
        np.testing.assert_array_equal(item["label"], label)


def test_road_anomaly_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="frames"):
        RoadAnomaly(tmp_path)
    _road_anomaly(tmp_path)
    (tmp_path / "frame_list.json").write_text("[not json")
    with pytest.raises(ValueError, match="frame_list.json"):
        RoadAnomaly(tmp_path)
    (tmp_path / "frame_list.json").write_text(json.dumps(["cows.jpg", "missing.jpg"]))
    with pytest.raises(FileNotFoundError, match="missing.jpg"):
        RoadAnomaly(tmp_path)
    (tmp_path / "frame_list.json").write_text(json.dumps(["cows.jpg", "rock.jpg"]))
    (tmp_path / "frames/cows.jpg").write_bytes(b"\xff\xd8\xff truncated")
    with pytest.raises(ValueError, match="cannot decode .*cows.jpg"):
        RoadAnomaly(tmp_path)[0]
    _write_label(tmp_path / "frames/rock.labels/labels_semantic.png", np.full((H, W), 1, np.uint8))
    with pytest.raises(ValueError, match=r"rock.labels/labels_semantic.png, got \[1\]"):
        RoadAnomaly(tmp_path)[1]


def test_road_anomaly_on_real_frames(road_anomaly_sample):
    root = road_anomaly_sample
    reader = RoadAnomaly(root)
    assert len(reader) == len(json.loads((root / "frame_list.json").read_text()))
    for i in range(len(reader)):
        item = reader[i]
        raw = cv2.imread(str(root / "frames" / f"{item['name']}.labels" / "labels_semantic.png"), cv2.IMREAD_UNCHANGED)
        assert item["image"].shape == raw.shape + (3,) and item["image"].dtype == np.uint8
        np.testing.assert_array_equal(item["label"], (raw == 2).astype(np.uint8))
        assert 0 < item["label"].mean() < 0.5
    # RGB order: the decoded image is the BGR file reversed
    bgr = cv2.imread(str(reader.frames[0][1]))
    np.testing.assert_array_equal(reader[0]["image"], bgr[..., ::-1])


# ----------------------------------------------------------------------------- SegmentMeIfYouCan

@pytest.mark.parametrize("extension", [".jpg", ".webp"])  # RoadAnomaly21, RoadObstacle21
def test_smiyc_lists_labelled_frames_and_reads_them(tmp_path, extension):
    label = _anomaly_label(1)
    image = np.full((H, W, 3), 90, np.uint8)
    _write_rgb(tmp_path / "images" / f"validation_1{extension}", image)
    _write_rgb(tmp_path / "images" / f"test_unlabelled{extension}", image)
    _write_label(tmp_path / "labels_masks" / "validation_1_labels_semantic.png", label)
    reader = SegmentMeIfYouCan(tmp_path)
    assert len(reader) == 1
    item = reader[0]
    assert item["name"] == "validation_1"
    np.testing.assert_array_equal(item["label"], label)
    assert np.abs(item["image"].astype(int) - 90).max() <= 2


def test_smiyc_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="images"):
        SegmentMeIfYouCan(tmp_path)
    (tmp_path / "images").mkdir()
    (tmp_path / "labels_masks").mkdir()
    with pytest.raises(FileNotFoundError, match="labels_masks"):
        SegmentMeIfYouCan(tmp_path)
    _write_label(tmp_path / "labels_masks" / "frame_7_labels_semantic.png", np.full((H, W), 3, np.uint8))
    with pytest.raises(FileNotFoundError, match="frame_7"):
        SegmentMeIfYouCan(tmp_path)
    _write_rgb(tmp_path / "images" / "frame_7.jpg", _image(0))
    with pytest.raises(ValueError, match=r"frame_7_labels_semantic.png, got \[3\]"):
        SegmentMeIfYouCan(tmp_path)[0]
    _write_label(tmp_path / "labels_masks" / "frame_7_labels_semantic.png", np.zeros((H + 1, W), np.uint8))
    with pytest.raises(ValueError, match="differs"):
        SegmentMeIfYouCan(tmp_path)[0]


def test_first_frames_is_a_prefix_view():
    from jaxanom.data.frames import FirstFrames

    source = [{"name": str(i)} for i in range(5)]
    assert [f["name"] for f in FirstFrames(source, 3)] == ["0", "1", "2"]
    assert len(FirstFrames(source, 9)) == 5
    with pytest.raises(IndexError):
        FirstFrames(source, 3)[3]
    with pytest.raises(ValueError, match="count"):
        FirstFrames(source, 0)
