"""Data: procedural street scenes, dataset readers (Cityscapes, CamVid, the anomaly sets, off-road), augmentations.

Readers and the generator need only NumPy and OpenCV; the grain input pipeline lives in
``jaxanom.data.pipeline`` and is imported on its own.
"""
from jaxanom.data.camvid import CamVid
from jaxanom.data.cityscapes import Cityscapes
from jaxanom.data.deepscene import DeepScene
from jaxanom.data.fishyscapes import FishyscapesLostAndFound, FishyscapesStatic
from jaxanom.data.lostandfound import LostAndFound
from jaxanom.data.offroad import OffroadSequence
from jaxanom.data.road_anomaly import RoadAnomaly
from jaxanom.data.rugd import RUGD
from jaxanom.data.smiyc import RoadAnomaly21, RoadObstacle21, SegmentMeIfYouCan
from jaxanom.data.synthetic import SyntheticScenes, generate

__all__ = ["CamVid", "Cityscapes", "DeepScene", "FishyscapesLostAndFound", "FishyscapesStatic", "LostAndFound",
           "OffroadSequence", "RUGD", "RoadAnomaly",
           "RoadAnomaly21", "RoadObstacle21", "SegmentMeIfYouCan", "SyntheticScenes", "generate"]
