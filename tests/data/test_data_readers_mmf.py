"""MMF's readers on fixtures in the official layouts: Cityscapes disparity + camera, Lost and
Found, SegmentMeIfYouCan with user-supplied depth; and on bad folders / files."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from jaxanom.data import Cityscapes, LostAndFound, SegmentMeIfYouCan

H, W = 6, 10
CAMERA = {"extrinsic": {"baseline": 0.209313, "pitch": 0.038, "roll": 0.0, "x": 1.7, "y": 0.0, "yaw": -0.0195,
                        "z": 1.3}, "intrinsic": {"fx": 2262.52, "fy": 2265.3017905988554, "u0": 1096.98, "v0": 513.137}}


def _write(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), array)


def _raw_disparity(seed):
    raw = np.random.default_rng(seed).integers(0, 30000, (H, W)).astype(np.uint16)
    raw[0, :3] = 0  # invalid
    return raw


def _expected(raw):  # the Cityscapes README's rule, written out
    out = np.zeros(raw.shape, np.float64)
    for index, p in np.ndenumerate(raw):
        out[index] = (float(p) - 1.0) / 256.0 if p > 0 else 0.0
    return out


def _cityscapes(root: Path, camera: bool = True):
    name, city = "aachen_000000_000019", "aachen"
    _write(root / "leftImg8bit/val" / city / f"{name}_leftImg8bit.png", np.zeros((H, W, 3), np.uint8))
    _write(root / "gtFine/val" / city / f"{name}_gtFine_labelIds.png", np.full((H, W), 7, np.uint8))
    raw = _raw_disparity(0)
    _write(root / "disparity/val" / city / f"{name}_disparity.png", raw)
    if camera:
        path = root / "camera/val" / city / f"{name}_camera.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(CAMERA))
    return raw


def test_cityscapes_reads_disparity_and_camera(tmp_path):
    raw = _cityscapes(tmp_path)
    frame = Cityscapes(tmp_path, "val", with_disparity=True)[0]
    assert frame["disparity"].dtype == np.float32
    np.testing.assert_allclose(frame["disparity"], _expected(raw), rtol=1e-6)
    assert frame["camera"] == {"baseline": 0.209313, "fx": 2262.52, "fy": 2265.3017905988554, "u0": 1096.98,
                               "v0": 513.137}
    assert "disparity" not in Cityscapes(tmp_path, "val")[0]  # off by default


def test_cityscapes_disparity_errors_name_the_file(tmp_path):
    _cityscapes(tmp_path, camera=False)
    with pytest.raises(FileNotFoundError, match="camera"):
        Cityscapes(tmp_path, "val", with_disparity=True)
    path = tmp_path / "camera/val/aachen/aachen_000000_000019_camera.json"
    path.parent.mkdir(parents=True)
    path.write_text('{"intrinsic": {}}')
    with pytest.raises(ValueError, match="baseline"):
        Cityscapes(tmp_path, "val", with_disparity=True)[0]
    _write(tmp_path / "disparity/val/aachen/aachen_000000_000019_disparity.png", np.zeros((H, W), np.uint8))
    path.write_text(json.dumps(CAMERA))
    with pytest.raises(ValueError, match="16-bit"):
        Cityscapes(tmp_path, "val", with_disparity=True)[0]


def _lost_and_found(root: Path):
    name, seq = "04_Maurener_Weg_8_000000_000030", "04_Maurener_Weg_8"
    image = np.random.default_rng(1).integers(0, 256, (H, W, 3), dtype=np.uint8)
    ids = np.random.default_rng(2).integers(0, 5, (H, W)).astype(np.uint8)  # 0 void, 1 free space, >= 2 obstacles
    _write(root / "leftImg8bit/test" / seq / f"{name}_leftImg8bit.png", image[..., ::-1])
    _write(root / "gtCoarse/test" / seq / f"{name}_gtCoarse_labelIds.png", ids)
    raw = _raw_disparity(3)
    _write(root / "disparity/test" / seq / f"{name}_disparity.png", raw)
    return image, ids, raw


def test_lost_and_found_maps_labels_to_the_road_roi(tmp_path):
    image, ids, raw = _lost_and_found(tmp_path)
    reader = LostAndFound(tmp_path)
    frame = reader[0]
    assert len(reader) == 1 and frame["name"] == "04_Maurener_Weg_8_000000_000030"
    np.testing.assert_array_equal(frame["image"], image)
    expected = np.select([ids == 0, ids == 1], [255, 0], 1)
    np.testing.assert_array_equal(frame["label"], expected)
    np.testing.assert_array_equal(frame["roi"], ids > 0)
    np.testing.assert_allclose(frame["disparity"], _expected(raw), rtol=1e-6)
    assert "camera" not in frame


def test_lost_and_found_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="Lost and Found images"):
        LostAndFound(tmp_path)
    _lost_and_found(tmp_path)
    next((tmp_path / "disparity/test").rglob("*.png")).unlink()
    with pytest.raises(FileNotFoundError, match="disparity"):
        LostAndFound(tmp_path)


def _obstacle_track(root: Path):
    _write(root / "images/validation_1.webp", np.zeros((H, W, 3), np.uint8))
    _write(root / "labels_masks/validation_1_labels_semantic.png", np.zeros((H, W), np.uint8))


def test_smiyc_with_user_depth(tmp_path):
    _obstacle_track(tmp_path / "track")
    raw = _raw_disparity(4)
    _write(tmp_path / "depth/validation_1_disparity.png", raw)
    frame = SegmentMeIfYouCan(tmp_path / "track", depth_root=tmp_path / "depth")[0]
    np.testing.assert_allclose(frame["disparity"], _expected(raw), rtol=1e-6)
    assert "disparity" not in SegmentMeIfYouCan(tmp_path / "track")[0]


def test_smiyc_depth_missing_is_a_clear_error(tmp_path):
    _obstacle_track(tmp_path / "track")
    with pytest.raises(FileNotFoundError, match="depth_root"):
        SegmentMeIfYouCan(tmp_path / "track", depth_root=tmp_path / "nowhere")
    (tmp_path / "depth").mkdir()
    with pytest.raises(FileNotFoundError, match="validation_1_disparity.png"):
        SegmentMeIfYouCan(tmp_path / "track", depth_root=tmp_path / "depth")
