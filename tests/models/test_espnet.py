"""ESPNet: our PyTorch rendering with random weights (random BN statistics and PReLU slopes) gives
the same logits once imported; the authors' Cityscapes checkpoint loads into both and agrees on a
real frame; the preprocessing, the run folder and the errors."""
import jax
import numpy as np
import pytest
import torch

from conftest import REALDATA
from jaxanom.cli import main
from jaxanom.app.evaluate import predictor
from jaxanom.app.experiment import Experiment, build_network, load_variables
from jaxanom.models import build_model, count_params
from jaxanom.models.espnet import ESPNet, normalize_espnet
from jaxanom.weights import from_torch, read_state_dict
from torch_reference import ESPNetTorch, nchw, nhwc, randomize_prelu

CHECKPOINT = REALDATA / "espnet" / "espnet_p_2_q_8.pth"
TOLERANCE = 1e-5  # max |difference| relative to the reference's max |value|; the reference is float64


def torch_logits(net, images: np.ndarray) -> np.ndarray:
    """Eval-mode logits of ``net`` in float64, channels-last."""
    with torch.no_grad():
        return nhwc(net.double()(nchw(images.astype(np.float64))))


def jax_logits(state, images: np.ndarray):
    model, variables = from_torch(state, "espnet-cityscapes")
    return model, np.asarray(jax.jit(lambda v, x: model.apply(v, x, train=False))(variables, images)["logits"])


def assert_close(got, want):
    assert got.shape == want.shape
    error = np.abs(got - want).max() / np.abs(want).max()
    assert error <= TOLERANCE, error


@pytest.fixture(scope="module")
def random_net():
    torch.manual_seed(0)
    return randomize_prelu(ESPNetTorch(classes=7, p=1, q=2), seed=0)


@pytest.mark.parametrize("p, q, classes, size", [(1, 2, 7, (40, 56)), (2, 3, 20, (24, 88))])
def test_random_espnet_gives_the_torch_logits(p, q, classes, size):
    torch.manual_seed(p)
    net = randomize_prelu(ESPNetTorch(classes, p, q), seed=p)
    images = np.random.default_rng(p).normal(size=(2, *size, 3)).astype(np.float32)
    want = torch_logits(net, images)
    model, got = jax_logits(net.state_dict(), images)
    assert (model.p, model.q, model.num_classes) == (p, q, classes)
    assert_close(got, want)


def test_every_tensor_is_used_and_a_missing_one_is_named(random_net):
    state = {k: v for k, v in random_net.state_dict().items() if k != "encoder.level2.0.bn.act.weight"}
    with pytest.raises(ValueError, match=r"missing \(1\): encoder\.level2\.0\.bn\.act\.weight"):
        from_torch(state, "espnet-cityscapes")
    extra = {**random_net.state_dict(), "encoder.level3.0.d32.conv.weight": torch.zeros(1, 1, 3, 3)}
    with pytest.raises(ValueError, match=r"unexpected \(1\): encoder\.level3\.0\.d32\.conv\.weight"):
        from_torch(extra, "espnet-cityscapes")
    encoder_only = {k: v for k, v in random_net.state_dict().items() if k.startswith("encoder.")}
    with pytest.raises(ValueError, match="classifier.weight"):
        from_torch(encoder_only, "espnet-cityscapes")


def test_normalize_espnet_is_the_authors_bgr_preprocessing():
    rgb = np.random.default_rng(1).integers(0, 256, size=(2, 5, 7, 3), dtype=np.uint8)
    mean, std = (72.3923111, 82.90893555, 73.15840149), (45.3192215, 46.15289307, 44.91483307)
    want = np.stack([(rgb[..., 2 - c].astype(np.float64) - mean[c]) / std[c] / 255 for c in range(3)], -1)
    np.testing.assert_allclose(normalize_espnet(rgb), want, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.asarray(jax.jit(normalize_espnet)(rgb)), want, rtol=1e-6, atol=1e-7)


def test_predictor_normalises_uint8_images_for_espnet(random_net):
    model, variables = from_torch(random_net.state_dict(), "espnet-cityscapes")
    rgb = np.random.default_rng(2).integers(0, 256, size=(1, 16, 24, 3), dtype=np.uint8)
    # jitted: one compile instead of one per primitive (the predictor is jitted too)
    want = jax.jit(lambda v, x: model.apply(v, x, train=False))(variables, normalize_espnet(rgb))["logits"]
    np.testing.assert_allclose(predictor(model, variables)(rgb)["logits"], want, rtol=1e-6, atol=1e-6)


def test_sizes_not_multiples_of_8_and_integer_images_are_refused():
    model = ESPNet(num_classes=5, p=1, q=1)
    with pytest.raises(ValueError, match="images: expected H and W multiples of 8, got 20x24"):
        model.init(jax.random.key(0), np.zeros((1, 20, 24, 3), np.float32))
    with pytest.raises(ValueError, match="images: expected a float dtype"):
        model.init(jax.random.key(0), np.zeros((1, 16, 16, 3), np.uint8))


def test_registry_and_experiment_build_espnet():
    assert build_model("espnet_p5_q3", num_classes=4) == ESPNet(num_classes=4, p=5, q=3)
    assert build_network(Experiment(model="espnet_p2_q8", num_classes=20, attention=None)) == ESPNet()
    assert build_network(Experiment(model="espnet_p2_q8", attention="cudam")) == ESPNet(
        num_classes=19, attention="cudam", attention_position="deep", attention_options=(("gate", "paper"),))
    with pytest.raises(ValueError, match=r"cudam_position: expected one of \('deep',\) for 'cudam'"):
        Experiment(model="espnet_p2_q8", attention="cudam", cudam_position="output")
    with pytest.raises(ValueError, match="espnet_p<P>_q<Q>, got 'espnet_p0_q8'"):
        build_model("espnet_p0_q8")


def test_converted_espnet_is_a_run_folder_with_the_imported_weights(random_net, tmp_path):
    torch.save(random_net.state_dict(), tmp_path / "espnet.pth")
    out = tmp_path / "run"
    assert main(["convert-weights", "--from", "espnet-cityscapes", str(tmp_path / "espnet.pth"), str(out)]) == 0
    experiment, variables = load_variables(out)  # what evaluate --run reads
    assert (experiment.model, experiment.num_classes, experiment.attention) == ("espnet_p1_q2", 7, None)
    _, want = from_torch(random_net.state_dict(), "espnet-cityscapes")
    assert jax.tree.structure(variables) == jax.tree.structure(want)
    jax.tree.map(np.testing.assert_array_equal, variables, want)


@pytest.fixture(scope="module")
def checkpoint():
    if not CHECKPOINT.is_file():
        pytest.skip(f"the ESPNet authors' Cityscapes checkpoint not found at {CHECKPOINT} (set JAXANOM_REALDATA)")
    return CHECKPOINT


def test_authors_checkpoint_loads_into_both_and_gives_the_same_logits(checkpoint):
    from jaxanom.data.cityscapes import Cityscapes
    import cv2

    net = ESPNetTorch(classes=20, p=2, q=8)
    net.load_state_dict(torch.load(checkpoint, map_location="cpu", weights_only=True), strict=True)
    frame = Cityscapes(REALDATA / "cityscapes8", "train")[0]
    image = normalize_espnet(cv2.resize(frame["image"], (256, 128), interpolation=cv2.INTER_AREA)[None])
    want = torch_logits(net.eval(), image)
    model, got = jax_logits(read_state_dict(checkpoint), image)
    assert model == ESPNet(num_classes=20, p=2, q=8)
    assert count_params(model) == sum(p.numel() for p in net.parameters())  # about 0.36M
    assert_close(got, want)
    assert (got.argmax(-1) == want.argmax(-1)).mean() > 0.999
