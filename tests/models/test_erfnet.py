"""ERFNet: our PyTorch rendering with random weights (random BN statistics) gives the same logits once
imported, from the authors' float layout and from the int8 layout (bn1 folded, weights quantised);
the real int8 file agrees with the rendering on a real crop; dropout, preprocessing, the run folder,
convert-weights' class count and the errors."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

from conftest import REALDATA
from jaxanom.app.evaluate import predictor
from jaxanom.app.experiment import Experiment, build_network, load_variables
from jaxanom.cli import main
from jaxanom.models import build_model, count_params
from jaxanom.models.erfnet import ERFNet, NonBottleneck1D, normalize_erfnet
from jaxanom.weights import from_torch, read_state_dict
from torch_reference import ERFNetTorch, ESPNetTorch, erfnet_int8_state, nchw, nhwc, randomize

INT8_FILE = REALDATA / "erfnet" / "erfnet_cityscapes_int8.pth"
IMAGES = np.random.default_rng(0).random((2, 24, 40, 3)).astype(np.float32)  # 3x5 at 1/8: dilations past the map
EXACT = 1e-6  # float64 on both sides; the logits are returned as float32 (relative rounding ~6e-8)


def torch_logits(net, images: np.ndarray) -> np.ndarray:
    """Eval-mode logits of ``net`` in float64, channels-last (``net`` is left in float32)."""
    with torch.no_grad():
        out = nhwc(net.double()(nchw(images.astype(np.float64))))
    net.float()
    return out


def jax_logits_float64(model, variables, images: np.ndarray) -> np.ndarray:
    with jax.enable_x64(True):
        wide = model.clone(dtype=jnp.float64)
        return np.asarray(jax.jit(lambda v, x: wide.apply(v, x, train=False))(variables, images.astype(np.float64))
                          ["logits"])


def relative_error(got, want) -> float:
    assert got.shape == want.shape
    return float(np.abs(got - want).max() / np.abs(want).max())


@pytest.fixture(scope="module")
def net():
    torch.manual_seed(0)
    return randomize(ERFNetTorch(classes=7), seed=0)


@pytest.fixture(scope="module")
def imported(net):
    """The rendering's weights saved as the authors' DataParallel checkpoint, imported."""
    return from_torch({f"module.{k}": v for k, v in net.state_dict().items()}, "erfnet-cityscapes")


def test_float_layout_gives_the_torch_logits_through_the_predictor(net, imported):
    """float32 here (the float64 comparison is the int8 layout's: the same network); uint8 images are
    scaled to [0, 1] by the predictor (``ERFNet.normalize_input``)."""
    model, variables = imported
    assert model == ERFNet(num_classes=7)
    rgb = np.random.default_rng(2).integers(0, 256, size=IMAGES.shape, dtype=np.uint8)
    np.testing.assert_array_equal(normalize_erfnet(rgb), rgb.astype(np.float32) / 255)
    got = np.asarray(predictor(model, variables)(rgb)["logits"])
    assert relative_error(got, torch_logits(net, rgb / 255)) <= 1e-5


def test_int8_layout_from_a_file_gives_the_dequantised_torch_logits(net, tmp_path):
    state, fused = erfnet_int8_state(net)
    torch.save(state, tmp_path / "int8.pth")
    arrays = read_state_dict(tmp_path / "int8.pth")  # no warning escapes (pytest makes them errors)
    offset = [k for k, v in state.items() if v.is_quantized and v.q_zero_point() != 0]
    assert len(offset) > 20  # many weights have a zero point, as in the real file
    for name in offset[:: len(offset) // 4]:
        np.testing.assert_array_equal(arrays[name], state[name].dequantize().numpy())
    model, variables = from_torch(arrays, "erfnet-cityscapes")
    for block in ("layers_1", "layers_14"):  # bn1, folded into conv1x3_1 in this layout, is x -> x exactly
        bn1 = {**variables["params"]["encoder"][block]["bn1"], **variables["batch_stats"]["encoder"][block]["bn1"]}
        assert (bn1["scale"] == 1).all() and (bn1["bias"] == 0).all() and (bn1["mean"] == 0).all()
        assert (bn1["var"] + np.float32(1e-3) == 1).all()
    assert relative_error(jax_logits_float64(model, variables, IMAGES), torch_logits(fused, IMAGES)) <= EXACT


def test_every_tensor_is_used_and_problems_are_named(net):
    state = net.state_dict()
    partly_fused = {k: v for k, v in state.items() if not k.startswith("encoder.layers.3.bn1.")}
    with pytest.raises(ValueError, match=r"missing \(4\): encoder\.layers\.3\.bn1\.bias; encoder\.layers\.3\.bn1\."):
        from_torch(partly_fused, "erfnet-cityscapes")
    extra = {**state, "decoder.layers.6.conv.weight": torch.zeros(1, 1, 3, 3),
             "decoder.layers.1.conv3x1_1.scale": torch.tensor(0.5)}  # the second is the int8 file's: dropped
    with pytest.raises(ValueError, match=r"unexpected \(1\): decoder\.layers\.6\.conv\.weight$"):
        from_torch(extra, "erfnet-cityscapes")
    encoder_only = {k: v for k, v in state.items() if k.startswith("encoder.")}
    with pytest.raises(ValueError, match="decoder.output_conv.weight"):
        from_torch(encoder_only, "erfnet-cityscapes")


def test_dropout_drops_whole_channels_in_training_only():
    """With the input far above zero no ReLU clips, so block(x) = z + x without dropout and, per
    sample and channel, x (dropped) or z / (1 - p) + x (kept) with it."""
    x = 100 + jnp.asarray(np.random.default_rng(1).normal(size=(3, 8, 6, 16)), jnp.float32)
    plain, dropped = NonBottleneck1D(dilation=2), NonBottleneck1D(dilation=2, dropout=0.5)
    variables = plain.init(jax.random.key(0), x, train=False)
    run = lambda block, train: block.apply(variables, x, train, rngs={"dropout": jax.random.key(3)},  # noqa: E731
                                           mutable=["batch_stats"])[0]
    z = run(plain, True) - x
    out = run(dropped, True)
    is_dropped = jnp.abs(out - x).max(axis=(1, 2)) < 1e-3
    assert 0 < is_dropped.mean() < 1  # some channels of some samples dropped, not all
    want = jnp.where(is_dropped[:, None, None, :], x, 2 * z + x)
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-3)
    np.testing.assert_array_equal(run(dropped, False), run(plain, False))  # eval: no dropout


def test_sizes_not_multiples_of_8_and_integer_images_are_refused():
    with pytest.raises(ValueError, match="images: expected H and W multiples of 8, got 20x24"):
        ERFNet().init(jax.random.key(0), np.zeros((1, 20, 24, 3), np.float32))
    with pytest.raises(ValueError, match="images: expected a float dtype"):
        ERFNet().init(jax.random.key(0), np.zeros((1, 16, 16, 3), np.uint8))


def test_registry_experiment_and_run_folder(net, imported, tmp_path):
    assert build_model("erfnet", num_classes=20) == ERFNet()
    assert build_network(Experiment(model="erfnet", num_classes=20, attention=None)) == ERFNet()
    assert build_network(Experiment(model="erfnet", attention="msaam")) == ERFNet(num_classes=19, attention="msaam")
    with pytest.raises(ValueError, match=r"cudam_position: expected one of \('deep',\) for 'cudam'"):
        Experiment(model="erfnet", attention="cudam", cudam_position="surface")
    torch.save({f"module.{k}": v for k, v in net.state_dict().items()}, tmp_path / "erfnet_pretrained.pth")
    out = tmp_path / "run"
    assert main(["convert-weights", "--from", "erfnet-cityscapes", str(tmp_path / "erfnet_pretrained.pth"),
                 str(out)]) == 0
    experiment, variables = load_variables(out)  # what evaluate --run and predict --run read
    assert (experiment.model, experiment.num_classes, experiment.attention) == ("erfnet", 7, None)
    want = imported[1]
    assert jax.tree.structure(variables) == jax.tree.structure(want)
    jax.tree.map(np.testing.assert_array_equal, variables, want)


@pytest.mark.parametrize("kind", ["espnet-cityscapes", "erfnet-cityscapes"])
def test_convert_weights_refuses_a_class_count_the_checkpoint_does_not_have(kind, tmp_path, capsys):
    torch.manual_seed(1)
    source = ESPNetTorch(classes=20, p=1, q=1) if kind == "espnet-cityscapes" else ERFNetTorch(classes=20)
    torch.save(source.state_dict(), tmp_path / "w.pth")
    code = main(["convert-weights", "--from", kind, "--num-classes", "5", str(tmp_path / "w.pth"), str(tmp_path / "o")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "--num-classes" in error and "(20); got 5" in error and len(error.splitlines()) == 1, error
    assert not (tmp_path / "o" / "experiment.json").exists()
    assert main(["convert-weights", "--from", kind, "--num-classes", "20", str(tmp_path / "w.pth"),
                 str(tmp_path / "o")]) == 0  # the checkpoint's own count is accepted


@pytest.fixture(scope="module")
def int8_file():
    if not INT8_FILE.is_file():
        pytest.skip(f"the ERFNet int8 weights not found at {INT8_FILE} (set JAXANOM_REALDATA)")
    return INT8_FILE


def test_real_int8_file_gives_the_renderings_logits_on_a_real_crop(int8_file):
    import cv2

    from jaxanom.data.cityscapes import Cityscapes

    arrays = read_state_dict(int8_file)
    fused = ERFNetTorch(classes=20, fused=True)
    fused.load_state_dict({k: torch.from_numpy(v) for k, v in arrays.items() if k in fused.state_dict()}, strict=True)
    frame = Cityscapes(REALDATA / "cityscapes8", "train")[0]
    image = normalize_erfnet(cv2.resize(frame["image"], (256, 128), interpolation=cv2.INTER_AREA)[None])
    want = torch_logits(fused.eval(), image)
    model, variables = from_torch(arrays, "erfnet-cityscapes")
    # 2.06M: the authors' float network (bn1 included), without the encoder-only classifier
    assert count_params(model) == sum(p.numel() for name, p in ERFNetTorch(classes=20).named_parameters()
                                      if not name.startswith("encoder.output_conv."))
    got = np.asarray(jax.jit(lambda v, x: model.apply(v, x, train=False))(variables, image)["logits"])  # float32
    assert relative_error(got, want) <= 1e-5
    assert (got.argmax(-1) == want.argmax(-1)).mean() > 0.999
