"""MMF's RGB-D module: AFC (Eq. 5) vs NumPy, adaptive pooling vs PyTorch, RGBDNet shapes and training."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

from jaxanom.models.rgbd import RGBDNet, depth_input
from jaxanom.nn.afc import AFC
from jaxanom.nn.spp import adaptive_avg_pool
from tiny_models import random_variables


def _afc_numpy(o, d, w1, b1, w2, b2):
    sigmoid = lambda z: 1 / (1 + np.exp(-z))  # noqa: E731
    g1 = sigmoid(o.mean(axis=(1, 2)) @ w1 + b1)[:, None, None, :]
    g2 = sigmoid(d.mean(axis=(1, 2)) @ w2 + b2)[:, None, None, :]
    return o * g1 + d * g2


@pytest.mark.parametrize("shape", [(2, 5, 7, 3), (1, 1, 1, 1), (3, 4, 9, 6)])
def test_afc_matches_eq5_in_numpy(shape):
    rng = np.random.default_rng(0)
    o, d = (rng.normal(size=shape).astype(np.float32) * 10 for _ in range(2))
    variables = AFC().init(jax.random.key(1), o, d)
    p = variables["params"]
    w1, b1 = np.asarray(p["rgb_gate"]["kernel"]), np.asarray(p["rgb_gate"]["bias"])
    w2, b2 = np.asarray(p["depth_gate"]["kernel"]), np.asarray(p["depth_gate"]["bias"])
    b1, b2 = b1 + rng.normal(size=b1.shape).astype(np.float32), b2 - 1.0  # non-zero biases
    params = {"rgb_gate": {"kernel": w1, "bias": b1}, "depth_gate": {"kernel": w2, "bias": b2}}
    got = AFC().apply({"params": params}, o, d)
    np.testing.assert_allclose(got, _afc_numpy(o.astype(np.float64), d.astype(np.float64), w1, b1, w2, b2),
                               rtol=1e-5, atol=1e-5)
    # zero kernels: F = sigmoid(b1) O + sigmoid(b2) Dp
    zero = {k: {"kernel": np.zeros_like(v["kernel"]), "bias": v["bias"]} for k, v in params.items()}
    got = AFC().apply({"params": zero}, o, d)
    np.testing.assert_allclose(got, o / (1 + np.exp(-b1)) + d / (1 + np.exp(-b2)), rtol=1e-5, atol=1e-5)
    # per example: the batched call equals a loop over examples
    loop = np.concatenate([AFC().apply({"params": params}, o[i:i + 1], d[i:i + 1]) for i in range(shape[0])])
    np.testing.assert_allclose(AFC().apply({"params": params}, o, d), loop, rtol=1e-6, atol=1e-6)


def test_afc_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="rgb, depth"):
        AFC().init(jax.random.key(0), jnp.zeros((1, 2, 2, 3)), jnp.zeros((1, 2, 2, 4)))


@pytest.mark.parametrize("hw, out", [((7, 11), (3, 4)), ((8, 16), (8, 16)), ((5, 3), (1, 1)), ((4, 6), (8, 2))])
def test_adaptive_avg_pool_matches_pytorch(hw, out):
    x = np.random.default_rng(1).normal(size=(2, *hw, 3)).astype(np.float32)
    expected = torch.nn.functional.adaptive_avg_pool2d(torch.from_numpy(x).permute(0, 3, 1, 2), out)
    np.testing.assert_allclose(adaptive_avg_pool(jnp.asarray(x), out), expected.permute(0, 2, 3, 1).numpy(),
                               rtol=1e-5, atol=1e-6)


def test_depth_input_is_clipped_normalised_disparity():
    disparity = np.array([[0.0, 16.0, 64.0, 1e6]], np.float32)
    np.testing.assert_allclose(depth_input(disparity, 256), [[0.0, 1.0, 1.0, 1.0]])
    np.testing.assert_allclose(depth_input(disparity, 1024), [[0.0, 0.25, 1.0, 1.0]])


def _tiny(num_classes=5):
    return RGBDNet(num_classes, "resnet_tiny", decoder_channels=16, spp_branch_channels=8)


def test_rgbdnet_shapes_depth_matters_and_compiles_once():
    model = _tiny()
    rng = np.random.default_rng(0)
    images = jnp.asarray(rng.normal(size=(2, 32, 48, 3)), jnp.float32)
    depth = jnp.asarray(rng.uniform(size=(2, 32, 48, 1)), jnp.float32)
    variables = random_variables(0, model.init, images, depth=depth)  # NumPy draws: an eager init compiles for seconds

    @jax.jit
    @chex.assert_max_traces(n=1)
    def forward(v, x, d):
        return model.apply(v, x, depth=d)["logits"]

    logits = forward(variables, images, depth)
    assert logits.shape == (2, 32, 48, 5) and logits.dtype == jnp.float32
    assert not np.allclose(forward(variables, images, 1 - depth), logits)  # depth changes the logits
    forward(variables, images * 2, depth)  # same shapes: no second trace
    with pytest.raises(ValueError, match="depth"):
        model.init(jax.random.key(0), images, depth=depth[..., 0])


def test_rgbdnet_trains_through_the_train_loop_and_fits_one_batch(tmp_path):
    from jaxanom.train.segmenter import TrainConfig, train
    from jaxanom.train.optim import OptimConfig
    from jaxanom.train.step import model_input

    rng = np.random.default_rng(0)
    left = rng.integers(8, 24, 4)[:, None, None]
    label = np.broadcast_to(np.arange(32)[None, None, :] >= left, (4, 32, 32)).astype(np.int32)
    depth = label[..., None].astype(np.float32)  # only the depth tells the classes apart
    batch = {"image": rng.integers(0, 256, (4, 32, 32, 3), dtype=np.uint8), "label": label, "depth": depth}
    config = TrainConfig(str(tmp_path), steps=40, save_every=1000, progress=False,
                         optim=OptimConfig(name="adamw", lr=3e-3, weight_decay=0.0))
    model = _tiny(2)
    # NumPy-drawn start (an init compiles for seconds; the train loop's own init is tested in test_train_segmenter.py)
    variables = random_variables(0, model.init, model_input(batch["image"]), depth=depth)
    state = train(config, model, iter([batch] * 40), variables=variables)
    logits = jax.jit(model.apply)(state.variables, model_input(batch["image"]), depth=depth)["logits"]  # one compile, not one per op
    accuracy = (np.argmax(logits, -1) == label).mean()
    assert accuracy > 0.8, accuracy
