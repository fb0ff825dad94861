"""Segmentation networks: ResNet backbones, DeepLabV3+, ESPNet, ERFNet, a registry by name; any of them carries a
registered attention module (``jaxanom.models.attention``: CuDAM, MSAAM, ...)."""
from jaxanom.models.deeplab import DeepLabV3Plus
from jaxanom.models.erfnet import ERFNet
from jaxanom.models.espnet import ESPNet
from jaxanom.models.registry import build_model, count_params, model_family, model_names
from jaxanom.models.resnet import RESNETS, ResNet, ResNetSpec

__all__ = ["DeepLabV3Plus", "ERFNet", "ESPNet", "ResNet", "ResNetSpec", "RESNETS", "build_model", "count_params", "model_family",
           "model_names"]
