"""SegmentMeIfYouCan inputs: a frame with two images and dataset names the official kit never reads."""
import cv2
import numpy as np
import pytest

from jaxanom.app.predict import SMIYC_DATASETS, PredictSettings
from jaxanom.data import SegmentMeIfYouCan

# The folders road-anomaly-benchmark (datasets/tracks.py, tracks_extra.py) reads maps from:
# each config's name_for_persistence, or that of the set its get_frame delegates to.
KIT_FOLDERS = {"AnomalyTrack-all", "ObstacleTrack-all", "LostAndFound-train", "LostAndFound-test",
               "RoadObstacleWeather-v1", "RoadObstacleExtra-v1", "SmallObstacleDataset-train",
               "SmallObstacleDataset-val", "SmallObstacleDataset-test"}


def test_a_frame_with_two_images_is_refused_naming_both(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "labels_masks").mkdir()
    cv2.imwrite(str(tmp_path / "labels_masks" / "1_labels_semantic.png"), np.zeros((4, 6), np.uint8))
    cv2.imwrite(str(tmp_path / "images" / "1.png"), np.zeros((4, 6, 3), np.uint8))
    assert len(SegmentMeIfYouCan(tmp_path)) == 1
    cv2.imwrite(str(tmp_path / "images" / "1.jpg"), np.full((4, 6, 3), 200, np.uint8))
    with pytest.raises(ValueError, match=r"1\.jpg and .*1\.png share the frame name '1'"):
        SegmentMeIfYouCan(tmp_path)


def test_predict_accepts_exactly_the_dataset_folders_the_kit_reads():
    assert set(SMIYC_DATASETS) == KIT_FOLDERS
    for name in SMIYC_DATASETS:
        assert PredictSettings(methods=("msp",), formats=("smiyc",), dataset=name).dataset == name
    for name in ("AnomalyTrack-al", "AnomalyTrack-validation", "ObstacleTrack-night", "FishyLAFAnomaly-val", "../up",
                 "", None):
        with pytest.raises(ValueError, match=f"dataset: .*AnomalyTrack-all.*got {name!r}"):
            PredictSettings(methods=("msp",), formats=("smiyc",), dataset=name)
    assert PredictSettings(methods=("msp",), dataset="anything").dataset == "anything"  # no smiyc format: unused
