"""Pretrained weights from PyTorch: torchvision ResNets and VGGs, the SML authors' DeepLabV3+, ESPNet, ERFNet.

    from jaxanom.weights import from_torch, read_state_dict

    state = read_state_dict("best_model.pth")      # or .npz / .safetensors (no torch needed)
    model, variables = from_torch(state, "sml-deeplabv3plus", num_classes=19)
    logits = model.apply(variables, images, train=False)["logits"]   # images ImageNet-normalised

``read_state_dict`` never unpickles arbitrary objects (``torch.load(weights_only=True)``);
``from_torch`` loads everything or raises a ValueError listing missing, unexpected and
mis-shaped keys. ``jaxanom.app.runs.write_run`` (``jaxanom convert-weights``) stores a DeepLabV3+, an ESPNet
(``from_torch(state, "espnet-cityscapes")``, the ESPNet authors' Cityscapes weights) or an ERFNet
(``"erfnet-cityscapes"``: the authors' float checkpoint or its int8 redistribution) as a run folder
that ``evaluate --run`` and ``train --init-from`` read; ``write_vgg`` / ``read_vgg`` store a VGG.
"""
from jaxanom.weights.architectures import KINDS, PRESETS, RUN_KINDS, SML_PRESET, from_torch, run_preset
from jaxanom.weights.files import read_state_dict, state_dict_arrays
from jaxanom.weights.store import read_vgg, take_modules, write_vgg

__all__ = ["KINDS", "PRESETS", "RUN_KINDS", "SML_PRESET", "from_torch", "read_state_dict", "read_vgg", "run_preset",
           "state_dict_arrays", "take_modules", "write_vgg"]
