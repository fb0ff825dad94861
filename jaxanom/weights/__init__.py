"""Pretrained weights from PyTorch: torchvision ResNets and VGGs, the SML authors' DeepLabV3+.

    from jaxanom.weights import from_torch, read_state_dict

    state = read_state_dict("best_model.pth")      # or .npz / .safetensors (no torch needed)
    model, variables = from_torch(state, "sml-deeplabv3plus", num_classes=19)
    logits = model.apply(variables, images, train=False)["logits"]   # images ImageNet-normalised

``read_state_dict`` never unpickles arbitrary objects (``torch.load(weights_only=True)``);
``from_torch`` loads everything or raises a ValueError listing missing, unexpected and
mis-shaped keys. ``jaxanom convert-weights`` writes the result as a run folder.
"""
from jaxanom.weights.architectures import KINDS, SML_PRESET, from_torch
from jaxanom.weights.files import read_state_dict, state_dict_arrays

__all__ = ["KINDS", "SML_PRESET", "from_torch", "read_state_dict", "state_dict_arrays"]
