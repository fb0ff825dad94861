"""PyTorch reference networks for the weight-import tests.

``torchvision_models()`` returns torchvision's ``models`` package. The torchvision wheel that
pip finds beside torch's CPU wheel is linked against CUDA libraries, so its C extension (detection
operators only) cannot load and ``import torchvision`` fails while registering them; the model
definitions are pure Python, so they are then imported without running ``torchvision/__init__``.

``ESPNetTorch`` is our own PyTorch rendering of the ESPNet authors' network (with the light decoder,
names as in their checkpoints), ``randomize_prelu`` also draws PReLU slopes.

``ERFNetTorch`` is our own PyTorch rendering of ERFNet (float layout, or ``fused`` without ``bn1``);
``erfnet_int8_state`` turns a float one into the int8 redistribution's layout.

``SMLDeepV3Plus`` is our own PyTorch rendering of the SML authors' ``DeepR101V3PlusD_OS8``
(github shjung13/Standardized-max-logits, ``network/deepv3.py`` and ``network/Resnet.py``), with
their parameter names so that their checkpoints' keys load into it: a deep stem packed as
``layer0``, ResNet-101 with the stride on the 3x3 conv, layer3 / layer4 dilated 2 / 4 with
stride-1 shortcuts, ASPP with the image-pooling branch first, ``bot_aspp``, ``bot_fine``,
``final1``, ``final2`` and the auxiliary ``dsn``; every resize bilinear with align_corners=True.
"""
from __future__ import annotations

import importlib
import importlib.util
import sys
import types

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F


def torchvision_models():
    try:
        return importlib.import_module("torchvision.models")
    except RuntimeError:  # "operator torchvision::nms does not exist": the CUDA build on CPU torch
        for name in [name for name in sys.modules if name == "torchvision" or name.startswith("torchvision.")]:
            del sys.modules[name]
        spec = importlib.util.find_spec("torchvision")
        package = types.ModuleType("torchvision")
        package.__path__ = list(spec.submodule_search_locations)
        package.__file__ = spec.origin
        sys.modules["torchvision"] = package
        return importlib.import_module("torchvision.models")


def randomize(module: nn.Module, seed: int) -> nn.Module:
    """Random BatchNorm affine parameters and running statistics (the default init has 1, 0, 0, 1),
    in eval mode."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for layer in module.modules():
            if isinstance(layer, nn.BatchNorm2d):
                n = layer.num_features
                layer.weight.copy_(torch.rand(n, generator=gen) + 0.5)
                layer.bias.copy_(torch.randn(n, generator=gen) * 0.1)
                layer.running_mean.copy_(torch.randn(n, generator=gen) * 0.1)
                layer.running_var.copy_(torch.rand(n, generator=gen) + 0.5)
            elif isinstance(layer, nn.Conv2d) and layer.bias is not None:
                layer.bias.copy_(torch.randn(layer.bias.shape, generator=gen) * 0.1)
    return module.eval()


def nchw(images: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(images.transpose(0, 3, 1, 2)))


def nhwc(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().permute(0, 2, 3, 1).numpy()


def _conv_bn_relu(cin: int, cout: int, kernel: int, stride: int = 1, dilation: int = 1) -> list[nn.Module]:
    pad = dilation * (kernel // 2)
    return [nn.Conv2d(cin, cout, kernel, stride, pad, dilation, bias=False), nn.BatchNorm2d(cout), nn.ReLU()]


class _Bottleneck(nn.Module):
    def __init__(self, cin: int, planes: int, stride: int, dilation: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride, dilation, dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, 4 * planes, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(4 * planes)
        self.downsample = None
        if stride != 1 or cin != 4 * planes:
            self.downsample = nn.Sequential(nn.Conv2d(cin, 4 * planes, 1, stride, bias=False),
                                            nn.BatchNorm2d(4 * planes))

    def forward(self, x):
        y = F.relu(self.bn1(self.conv1(x)))
        y = F.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        return F.relu(y + (x if self.downsample is None else self.downsample(x)))


def _stage(cin: int, planes: int, blocks: int, stride: int, dilation: int) -> nn.Sequential:
    layers = [_Bottleneck(cin, planes, stride, dilation)]
    layers += [_Bottleneck(4 * planes, planes, 1, dilation) for _ in range(blocks - 1)]
    return nn.Sequential(*layers)


class _ASPP(nn.Module):
    def __init__(self, cin: int, width: int, rates: tuple[int, ...]):
        super().__init__()
        self.features = nn.ModuleList([nn.Sequential(*_conv_bn_relu(cin, width, 1))]
                                      + [nn.Sequential(*_conv_bn_relu(cin, width, 3, 1, r)) for r in rates])
        self.img_conv = nn.Sequential(*_conv_bn_relu(cin, width, 1))

    def forward(self, x):
        pooled = self.img_conv(x.mean(dim=(2, 3), keepdim=True))
        branches = [F.interpolate(pooled, size=x.shape[2:], mode="bilinear", align_corners=True)]
        return torch.cat(branches + [branch(x) for branch in self.features], dim=1)


class SMLDeepV3Plus(nn.Module):
    """DeepR101V3PlusD_OS8 (``blocks`` (3, 4, 23, 3)); ``forward`` returns eval-mode logits NCHW."""

    def __init__(self, num_classes: int = 19, blocks: tuple[int, ...] = (3, 4, 23, 3)):
        super().__init__()
        self.layer0 = nn.Sequential(*_conv_bn_relu(3, 64, 3, 2), *_conv_bn_relu(64, 64, 3),
                                    *_conv_bn_relu(64, 128, 3), nn.MaxPool2d(3, 2, 1))
        self.layer1 = _stage(128, 64, blocks[0], 1, 1)
        self.layer2 = _stage(256, 128, blocks[1], 2, 1)
        self.layer3 = _stage(512, 256, blocks[2], 1, 2)
        self.layer4 = _stage(1024, 512, blocks[3], 1, 4)
        self.aspp = _ASPP(2048, 256, (12, 24, 36))
        self.bot_fine = nn.Sequential(*_conv_bn_relu(256, 48, 1))
        self.bot_aspp = nn.Sequential(*_conv_bn_relu(1280, 256, 1))
        self.final1 = nn.Sequential(*_conv_bn_relu(304, 256, 3), *_conv_bn_relu(256, 256, 3))
        self.final2 = nn.Sequential(nn.Conv2d(256, num_classes, 1))
        self.dsn = nn.Sequential(nn.Conv2d(1024, 512, 3, padding=1), nn.BatchNorm2d(512), nn.ReLU(),
                                 nn.Dropout2d(0.1), nn.Conv2d(512, num_classes, 1))

    def forward(self, x):
        low = self.layer1(self.layer0(x))
        deep = self.layer4(self.layer3(self.layer2(low)))
        up = F.interpolate(self.bot_aspp(self.aspp(deep)), size=low.shape[2:], mode="bilinear",
                           align_corners=True)
        logits = self.final2(self.final1(torch.cat([self.bot_fine(low), up], dim=1)))
        return F.interpolate(logits, size=x.shape[2:], mode="bilinear", align_corners=True)


# ----------------------------------------------------------------------------- ESPNet
# Our own rendering of the ESPNet authors' ``ESPNet`` (github sacmehta/ESPNet, ``train/Model.py``),
# written from the paper and the key names of their checkpoints: the same module names, so their
# state dicts load into it; NCHW; BN eps 1e-3; PReLU with one slope per channel.
class _BR(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.bn, self.act = nn.BatchNorm2d(channels, eps=1e-3), nn.PReLU(channels)

    def forward(self, x):
        return self.act(self.bn(x))


class _CBR(_BR):
    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1):
        super().__init__(cout)
        self.conv = nn.Conv2d(cin, cout, kernel, stride, kernel // 2, bias=False)

    def forward(self, x):
        return super().forward(self.conv(x))


class _C(nn.Module):  # a bias-free conv wrapped as ``.conv``, as the authors' C / CDilated
    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, dilation: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel, stride, dilation * (kernel // 2), dilation, bias=False)

    def forward(self, x):
        return self.conv(x)


class _ESP(nn.Module):
    """Strided (``bn`` and ``act`` directly) or not (``bn`` is a _BR, residual when cin == cout and add)."""

    def __init__(self, cin: int, cout: int, strided: bool = False, add: bool = True):
        super().__init__()
        n = cout // 5
        self.c1 = _C(cin, n, 3, 2) if strided else _C(cin, n, 1)
        self.d1 = _C(n, cout - 4 * n, 3)
        self.d2, self.d4, self.d8, self.d16 = (_C(n, n, 3, 1, d) for d in (2, 4, 8, 16))
        self.strided, self.add = strided, add and cin == cout and not strided
        if strided:
            self.bn, self.act = nn.BatchNorm2d(cout, eps=1e-3), nn.PReLU(cout)
        else:
            self.bn = _BR(cout)

    def forward(self, x):
        r = self.c1(x)
        a2 = self.d2(r)
        a4 = a2 + self.d4(r)
        a8 = a4 + self.d8(r)
        a16 = a8 + self.d16(r)
        y = torch.cat([self.d1(r), a2, a4, a8, a16], 1)
        if self.add:
            y = x + y
        return self.act(self.bn(y)) if self.strided else self.bn(y)


class _ESPEncoder(nn.Module):
    def __init__(self, classes: int, p: int, q: int):
        super().__init__()
        self.level1 = _CBR(3, 16, 3, 2)
        self.b1 = _BR(19)
        self.level2_0 = _ESP(19, 64, strided=True)
        self.level2 = nn.ModuleList([_ESP(64, 64) for _ in range(p)])
        self.b2 = _BR(131)
        self.level3_0 = _ESP(131, 128, strided=True)
        self.level3 = nn.ModuleList([_ESP(128, 128) for _ in range(q)])
        self.b3 = _BR(256)
        self.classifier = _C(256, classes, 1)


class ESPNetTorch(nn.Module):
    """ESPNet with the light decoder; ``forward`` returns eval-mode logits NCHW at the input size."""

    def __init__(self, classes: int = 20, p: int = 2, q: int = 8):
        super().__init__()
        self.encoder = _ESPEncoder(classes, p, q)
        self.level3_C = _C(131, classes, 1)
        self.br = nn.BatchNorm2d(classes, eps=1e-3)
        self.conv = _CBR(16 + classes, classes, 3)
        self.up_l3 = nn.Sequential(nn.ConvTranspose2d(classes, classes, 2, 2, bias=False))
        self.combine_l2_l3 = nn.Sequential(_BR(2 * classes), _ESP(2 * classes, classes, add=False))
        self.up_l2 = nn.Sequential(nn.ConvTranspose2d(classes, classes, 2, 2, bias=False), _BR(classes))
        self.classifier = nn.ConvTranspose2d(classes, classes, 2, 2, bias=False)

    def forward(self, x):
        e = self.encoder
        pool = nn.AvgPool2d(3, 2, 1)  # count_include_pad=True
        half = pool(x)
        s1 = e.level1(x)
        d2 = e.level2_0(e.b1(torch.cat([s1, half], 1)))
        y2 = d2
        for layer in e.level2:
            y2 = layer(y2)
        t2 = e.b2(torch.cat([y2, d2, pool(half)], 1))
        d3 = e.level3_0(t2)
        y3 = d3
        for layer in e.level3:
            y3 = layer(y3)
        c8 = e.classifier(e.b3(torch.cat([d3, y3], 1)))
        x = self.combine_l2_l3(torch.cat([self.level3_C(t2), self.up_l3(self.br(c8))], 1))
        return self.classifier(self.conv(torch.cat([self.up_l2(x), s1], 1)))


def randomize_prelu(module: nn.Module, seed: int) -> nn.Module:
    """``randomize`` plus random PReLU slopes in [-0.5, 1] (the default 0.25 everywhere would hide a
    slope put on the wrong channel or layer)."""
    randomize(module, seed)
    gen = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for layer in module.modules():
            if isinstance(layer, nn.PReLU):
                layer.weight.copy_(torch.rand(layer.weight.shape, generator=gen) * 1.5 - 0.5)
    return module


# ----------------------------------------------------------------------------- ERFNet
# Our own rendering of ERFNet (Romera et al., T-ITS 2018) from its description: module names as in
# the authors' checkpoints (``encoder.initial_block``, ``encoder.layers.<i>``, ``decoder.layers.<i>``,
# ``decoder.output_conv``), so their state dicts load into it; NCHW; eval mode (no dropout).
class _Downsampler(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout - cin, 3, 2, 1)
        self.bn = nn.BatchNorm2d(cout, eps=1e-3)

    def forward(self, x):
        return F.relu(self.bn(torch.cat([self.conv(x), F.max_pool2d(x, 2)], 1)))


class _NonBottleneck1D(nn.Module):
    """``fused=True``: ``bn1`` folded into ``conv1x3_1`` (the int8 redistribution's layout)."""

    def __init__(self, channels: int, dilation: int, fused: bool = False):
        super().__init__()
        d = dilation
        self.conv3x1_1 = nn.Conv2d(channels, channels, (3, 1), padding=(1, 0))
        self.conv1x3_1 = nn.Conv2d(channels, channels, (1, 3), padding=(0, 1))
        self.bn1 = nn.Identity() if fused else nn.BatchNorm2d(channels, eps=1e-3)
        self.conv3x1_2 = nn.Conv2d(channels, channels, (3, 1), padding=(d, 0), dilation=(d, 1))
        self.conv1x3_2 = nn.Conv2d(channels, channels, (1, 3), padding=(0, d), dilation=(1, d))
        self.bn2 = nn.BatchNorm2d(channels, eps=1e-3)

    def forward(self, x):
        y = F.relu(self.bn1(self.conv1x3_1(F.relu(self.conv3x1_1(x)))))
        y = self.bn2(self.conv1x3_2(F.relu(self.conv3x1_2(y))))
        return F.relu(y + x)


class _Upsampler(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv = nn.ConvTranspose2d(cin, cout, 3, 2, padding=1, output_padding=1)
        self.bn = nn.BatchNorm2d(cout, eps=1e-3)

    def forward(self, x):
        return F.relu(self.bn(self.conv(x)))


class _ERFEncoder(nn.Module):
    def __init__(self, classes: int, fused: bool):
        super().__init__()
        self.initial_block = _Downsampler(3, 16)
        blocks = [_Downsampler(16, 64), *(_NonBottleneck1D(64, 1, fused) for _ in range(5)), _Downsampler(64, 128)]
        blocks += [_NonBottleneck1D(128, d, fused) for _ in range(2) for d in (2, 4, 8, 16)]
        self.layers = nn.ModuleList(blocks)
        self.output_conv = nn.Conv2d(128, classes, 1)  # the encoder-only training's classifier; unused here

    def forward(self, x):
        x = self.initial_block(x)
        for layer in self.layers:
            x = layer(x)
        return x


class _ERFDecoder(nn.Module):
    def __init__(self, classes: int, fused: bool):
        super().__init__()
        blocks = [_Upsampler(128, 64), _NonBottleneck1D(64, 1, fused), _NonBottleneck1D(64, 1, fused)]
        blocks += [_Upsampler(64, 16), _NonBottleneck1D(16, 1, fused), _NonBottleneck1D(16, 1, fused)]
        self.layers = nn.ModuleList(blocks)
        self.output_conv = nn.ConvTranspose2d(16, classes, 2, 2)

    def forward(self, x):
        for layer in self.layers:
            x = layer(x)
        return self.output_conv(x)


class ERFNetTorch(nn.Module):
    """ERFNet; ``forward`` returns eval-mode logits NCHW at the input size. ``fused``: without ``bn1``
    (the int8 redistribution folded it into ``conv1x3_1``)."""

    def __init__(self, classes: int = 20, fused: bool = False):
        super().__init__()
        self.encoder = _ERFEncoder(classes, fused)
        self.decoder = _ERFDecoder(classes, fused)

    def forward(self, x):
        return self.decoder(self.encoder(x))


def erfnet_int8_state(net: ERFNetTorch) -> dict:
    """The state dict of ``net`` (float, with ``bn1``) in the int8 redistribution's layout: each
    block's ``bn1`` folded into ``conv1x3_1``, every conv weight quantised per tensor to qint8
    (affine over [min, max]: a non-zero zero point, as in the real file), ``*.scale`` / ``*.zero_point``
    output quantisation
    entries beside each conv, BN and residual add, and ``quant.*``. Also returns the fused float
    network whose weights are the dequantised ones: ``(state, ERFNetTorch(fused=True))``."""
    import warnings

    fused = ERFNetTorch(net.decoder.output_conv.out_channels, fused=True).eval()
    float_state = {}
    with torch.no_grad():
        for name, value in net.state_dict().items():
            if ".bn1." not in name:
                float_state[name] = value.clone()
        for name, module in net.named_modules():
            if isinstance(module, _NonBottleneck1D):
                bn, conv = module.bn1, module.conv1x3_1
                factor = bn.weight / torch.sqrt(bn.running_var + bn.eps)
                float_state[f"{name}.conv1x3_1.weight"] = conv.weight * factor[:, None, None, None]
                float_state[f"{name}.conv1x3_1.bias"] = (conv.bias - bn.running_mean) * factor + bn.bias
    state, gen = {}, torch.Generator().manual_seed(7)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*quantize_per_tensor.*deprecated", category=UserWarning)
        for name, value in float_state.items():
            module, leaf = name.rsplit(".", 1)
            if leaf == "weight" and value.ndim == 4:
                low, high = float(value.min()), float(value.max())
                scale = (high - low) / 255
                q = torch.quantize_per_tensor(value, scale, int(round(-128 - low / scale)), torch.qint8)
                state[name] = q
                float_state[name] = q.dequantize()
                state[f"{module}.scale"] = torch.rand((), generator=gen)
                state[f"{module}.zero_point"] = torch.tensor(128)
            else:
                state[name] = value
            if leaf == "running_var":
                state[f"{module}.scale"] = torch.rand(1, generator=gen)
                state[f"{module}.zero_point"] = torch.tensor([128])
        for name, module in net.named_modules():
            if isinstance(module, _NonBottleneck1D):
                state[f"{name}.skip_add.scale"] = torch.rand((), generator=gen)
                state[f"{name}.skip_add.zero_point"] = torch.tensor(128)
    state["quant.scale"], state["quant.zero_point"] = torch.tensor([0.0079]), torch.tensor([0])
    fused.load_state_dict(float_state, strict=True)
    return state, fused
