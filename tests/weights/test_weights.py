"""jaxanom.weights: PyTorch networks with random weights (and random BatchNorm statistics) give the
same outputs once imported, at odd input sizes; bad files and mismatched checkpoints are refused."""
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
from torch.nn import functional as F

from jaxanom.models import RESNETS, ResNet
from jaxanom.models.vgg import PERCEPTUAL_TAPS, VGG
from jaxanom.nn.layers import resize_bilinear
from jaxanom.weights import from_torch, read_state_dict
from torch_reference import SMLDeepV3Plus, nchw, nhwc, randomize, torchvision_models

IMAGES = np.random.default_rng(0).normal(size=(2, 35, 43, 3)).astype(np.float32)  # odd sizes
TOLERANCE = 1e-4  # max |difference| relative to the reference's max |value|, float32


def assert_close(got, want):
    got, want = np.asarray(got), np.asarray(want)
    assert got.shape == want.shape
    assert np.abs(got - want).max() <= TOLERANCE * np.abs(want).max()


@pytest.fixture(scope="module")
def tv():
    return torchvision_models()


@pytest.fixture(scope="module")
def sml(tmp_path_factory):
    """The SML network in PyTorch, saved as the authors' training checkpoints are: DataParallel's
    ``module.`` prefix inside ``state_dict``, beside optimizer state."""
    torch.manual_seed(0)
    net = randomize(SMLDeepV3Plus(num_classes=19), seed=0)
    path = tmp_path_factory.mktemp("sml") / "best.pth"
    torch.save({"state_dict": {f"module.{k}": v for k, v in net.state_dict().items()},
                "optimizer": {"state": {}, "param_groups": [{"lr": 0.01, "momentum": 0.9}]}, "epoch": 3}, path)
    with torch.no_grad():
        logits = nhwc(net(nchw(IMAGES)))
    return net, read_state_dict(path), logits


def torchvision_stages(net, images):
    """layer1 .. layer4 of a torchvision ResNet, channels-last."""
    out = {}
    with torch.no_grad():
        x = net.maxpool(net.relu(net.bn1(net.conv1(nchw(images)))))
        for i in range(1, 5):
            x = getattr(net, f"layer{i}")(x)
            out[f"layer{i}"] = nhwc(x)
    return out


# ----------------------------------------------------------------------------- the SML network
def test_sml_checkpoint_gives_the_same_logits(sml):
    net, state, want = sml
    assert not any(k.startswith("module.") for k in state) and "dsn.0.weight" in state
    model, variables = from_torch(state, "sml-deeplabv3plus", num_classes=19)
    assert (model.output_stride, model.resize, model.backbone) == (8, "align_corners", "resnet101_deep_stem")
    got = jax.jit(lambda v, x: model.apply(v, x, train=False))(variables, IMAGES)["logits"]
    assert_close(got, want)


def test_sml_wrong_class_count_names_the_classifier(sml):
    with pytest.raises(ValueError, match=r"mis-shaped \(2\): final2\.0\.bias: checkpoint \(19,\), expected \(10,\); "
                                         r"final2\.0\.weight: checkpoint \(19, 256, 1, 1\), expected \(10, 256, 1, 1\)$"):
        from_torch(sml[1], "sml-deeplabv3plus", num_classes=10)


def test_another_architecture_is_refused_with_missing_and_unexpected_keys(sml, tv):
    with pytest.raises(ValueError, match=r"(?s)missing \(482\): aspp.*unexpected \(7\): conv1\.weight; bn1\.weight; "
                                         r"bn1\.bias; bn1\.running_mean; bn1\.running_var; fc\.weight; fc\.bias\. "
                                         r"mis-shaped \(23\): layer1\.0\.conv1\.weight: checkpoint \(64, 64, 3, 3\)"):
        from_torch(tv.resnet18().state_dict(), "sml-deeplabv3plus")
    with pytest.raises(ValueError, match=r"(?s)missing \(5\): bn1\.bias; bn1\.running_mean; bn1\.running_var; "
                                         r"bn1\.weight; conv1\.weight\. unexpected \(\d+\): layer0\.0\.weight"):
        from_torch(sml[1], "torchvision-resnet101", key=jax.random.key(0))


def test_missing_key_and_non_finite_values_are_refused(sml):
    state = dict(sml[1])
    del state["layer3.7.bn2.running_var"]
    with pytest.raises(ValueError, match=r"missing \(1\): layer3\.7\.bn2\.running_var$"):
        from_torch(state, "sml-deeplabv3plus")
    state = {**sml[1], "final1.0.weight": np.full_like(sml[1]["final1.0.weight"], np.nan)}
    with pytest.raises(ValueError, match=r"not finite floating-point tensors \(1\): final1\.0\.weight \(\d+ NaN/Inf\)"):
        from_torch(state, "sml-deeplabv3plus")


# ----------------------------------------------------------------------------- torchvision ResNets
@pytest.mark.parametrize("name", ["resnet18", "resnet50"])
def test_torchvision_resnet_backbone_gives_the_same_features(tv, name):
    torch.manual_seed(1)
    net = randomize(getattr(tv, name)(), seed=1)
    model, variables = from_torch(net.state_dict(), f"torchvision-{name}", num_classes=5, key=jax.random.key(3))
    assert model.backbone == name and model.num_classes == 5
    backbone = {collection: variables[collection]["backbone"] for collection in ("params", "batch_stats")}
    got = jax.jit(lambda v, x: ResNet(RESNETS[name], 32).apply(v, x, train=False))(backbone, IMAGES)
    for stage, want in torchvision_stages(net, IMAGES).items():
        assert_close(got[stage], want)
    # the head is model.init's with the given key (XLA computes only what is returned)
    head = jax.jit(lambda: {k: v for k, v in model.init(jax.random.key(3), IMAGES[:1], train=False)["params"].items()
                            if k != "backbone"})()
    jax.tree.map(np.testing.assert_array_equal, {k: v for k, v in variables["params"].items() if k != "backbone"},
                 head)


def test_torchvision_resnet101_loads_every_tensor(tv):
    net = tv.resnet101()
    state = net.state_dict()
    _, variables = from_torch(state, "torchvision-resnet101", key=jax.random.key(0))
    block = variables["params"]["backbone"]["layer3_22"]["conv2"]
    np.testing.assert_array_equal(block["conv"]["kernel"], state["layer3.22.conv2.weight"].numpy().transpose(2, 3, 1, 0))
    np.testing.assert_array_equal(variables["batch_stats"]["backbone"]["layer3_22"]["conv2"]["bn"]["var"],
                                  state["layer3.22.bn2.running_var"].numpy())
    with pytest.raises(ValueError, match=r"missing \(\d+\): layer3\.6\.bn1\.bias; "):
        from_torch(tv.resnet50().state_dict(), "torchvision-resnet101", key=jax.random.key(0))


def test_torchvision_resnet_needs_a_key_and_kind_is_checked(tv):
    state = tv.resnet18().state_dict()
    with pytest.raises(ValueError, match="key"):
        from_torch(state, "torchvision-resnet18")
    with pytest.raises(ValueError, match="kind"):
        from_torch(state, "torchvision-resnet34", key=jax.random.key(0))


# ----------------------------------------------------------------------------- torchvision VGGs
@pytest.fixture(scope="module")
def vgg19(tv):
    torch.manual_seed(2)
    net = randomize(tv.vgg19(), seed=2)
    with torch.no_grad():
        x, features = nchw(IMAGES), []
        for layer in net.features:
            x = layer(x)
            features.append(nhwc(x))
    return net, features


@pytest.mark.parametrize("config, taps", [
    ("vgg16", {"relu1_2": 3, "relu2_2": 8, "relu3_3": 15, "relu4_3": 22, "relu5_3": 29}),
    ("vgg19", {"relu1_2": 3, "relu2_2": 8, "relu3_4": 17, "relu4_4": 26, "relu5_4": 35}),
])
def test_torchvision_vgg_gives_the_same_features(tv, vgg19, config, taps):
    if config == "vgg19":
        net, features = vgg19
    else:
        torch.manual_seed(2)
        net = randomize(tv.vgg16(), seed=2)
        with torch.no_grad():
            x, features = nchw(IMAGES), []
            for layer in net.features:
                x = layer(x)
                features.append(nhwc(x))
    model, variables = from_torch(net.state_dict(), f"torchvision-{config}")
    got = jax.jit(lambda v, x: model.apply(v, x, train=False))(variables, IMAGES)
    assert set(got) == set(taps)
    for tap, index in taps.items():
        assert isinstance(net.features[index], torch.nn.ReLU)
        assert_close(got[tap], features[index])


def test_vgg_other_taps_reuse_the_loaded_weights(vgg19):
    net, features = vgg19
    _, variables = from_torch(net.state_dict(), "torchvision-vgg19")
    got = VGG("vgg19", taps=PERCEPTUAL_TAPS).apply(variables, IMAGES)
    for tap, index in zip(PERCEPTUAL_TAPS, (1, 6, 11, 20)):
        assert_close(got[tap], features[index])
    with pytest.raises(ValueError, match="taps"):
        VGG("vgg16", taps=("relu3_4",))
    with pytest.raises(ValueError, match=r"missing \(2\): features\.34\.bias; features\.34\.weight$"):
        from_torch({k: v for k, v in net.state_dict().items() if not k.startswith("features.34")}, "torchvision-vgg19")


# ----------------------------------------------------------------------------- files
def test_npz_and_safetensors_read_as_the_torch_file(tmp_path, tv):
    from safetensors.numpy import save_file

    state = {k: v.numpy() for k, v in tv.resnet18().state_dict().items()}
    torch.save({k: torch.from_numpy(v) for k, v in state.items()}, tmp_path / "a.pth")
    np.savez(tmp_path / "a.npz", **state)
    save_file(state, tmp_path / "a.safetensors")
    first = read_state_dict(tmp_path / "a.pth")
    for suffix in ("npz", "safetensors"):
        other = read_state_dict(tmp_path / f"a.{suffix}")
        assert other.keys() == first.keys()
        for key in first:
            np.testing.assert_array_equal(other[key], first[key])


class NotATensor:
    pass


class RunsACommand:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):  # unpickling calls os.system (posix.system): code run by reading the file
        return os.system, (f"touch {self.marker}",)


def test_unsafe_and_damaged_files_are_refused(tmp_path):
    torch.save({"state_dict": {"w": torch.ones(2)}, "extra": NotATensor()}, tmp_path / "pickled.pth")
    with pytest.raises(ValueError, match="refused: it holds Python objects besides tensors .*NotATensor"):
        read_state_dict(tmp_path / "pickled.pth")
    # told by what the pickle references (torch's scan), whatever torch's message: a function, a whole module
    torch.save({"w": torch.ones(2), "x": RunsACommand(tmp_path / "ran")}, tmp_path / "system.pth")
    with pytest.raises(ValueError, match=r"refused: it holds Python objects besides tensors \(globals "
                                         rf"{os.system.__module__}\.system\)"):
        read_state_dict(tmp_path / "system.pth")
    assert not (tmp_path / "ran").exists()
    torch.save(torch.nn.Conv2d(1, 1, 1), tmp_path / "module.pth")
    with pytest.raises(ValueError, match=r"refused: .*\(globals torch\.nn\.modules\.conv\.Conv2d"):
        read_state_dict(tmp_path / "module.pth")
    for name in ("damaged.pth", "damaged.npz", "damaged.safetensors"):
        (tmp_path / name).write_bytes(b"\x80\x02not a checkpoint" * 7)
        with pytest.raises(ValueError, match="not a readable"):
            read_state_dict(tmp_path / name)
    with pytest.raises(ValueError, match="existing file"):
        read_state_dict(tmp_path / "absent.pth")
    torch.save({"w": torch.ones(2), "module.w": torch.ones(2)}, tmp_path / "twice.pth")
    with pytest.raises(ValueError, match="module"):
        read_state_dict(tmp_path / "twice.pth")


# ----------------------------------------------------------------------------- corner-aligned resize
@pytest.mark.parametrize("src, dst", [((5, 7), (35, 43)), ((9, 11), (4, 3)), ((1, 1), (3, 5)), ((6, 2), (1, 1))])
def test_align_corners_resize_matches_pytorch(src, dst):
    x = np.random.default_rng(1).normal(size=(2, *src, 3)).astype(np.float32)
    want = nhwc(F.interpolate(nchw(x), size=dst, mode="bilinear", align_corners=True))
    got = resize_bilinear(jnp.asarray(x), *dst, align_corners=True)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
