"""SPADE vs a NumPy reading of its formula; DissimilarityNet shapes, inputs, compile-once, fitting."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.models.dissimilarity import DissimilarityNet, anomaly_probability
from jaxanom.nn.spade import SPADE, resize_nearest
from tiny_models import random_variables


def _conv3x3(x, kernel, bias):
    """'same' 3x3 cross-correlation, zero padding: (B, H, W, I) x (3, 3, I, O)."""
    padded = np.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)))
    h, w = x.shape[1:3]
    out = sum(np.einsum("bhwi,io->bhwo", padded[:, dy:dy + h, dx:dx + w], kernel[dy, dx])
              for dy in range(3) for dx in range(3))
    return out + bias


@pytest.mark.parametrize("x_hw, s_hw", [((4, 6), (8, 12)), ((5, 3), (7, 7)), ((3, 3), (3, 3))])
def test_spade_matches_its_formula(x_hw, s_hw):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2, *x_hw, 3)).astype(np.float32) * 5 + 2
    s = rng.normal(size=(2, *s_hw, 4)).astype(np.float32)
    module = SPADE(hidden=5)
    variables = module.init(jax.random.key(0), x, s, train=False)
    p = jax.tree.map(np.asarray, variables["params"])
    got, _ = module.apply(variables, x, s, train=True, mutable=["batch_stats"])

    rows = np.floor(np.arange(x_hw[0]) * s_hw[0] / x_hw[0]).astype(int)
    cols = np.floor(np.arange(x_hw[1]) * s_hw[1] / x_hw[1]).astype(int)
    s_small = s[:, rows][:, :, cols].astype(np.float64)
    shared = np.maximum(_conv3x3(s_small, p["shared"]["kernel"], p["shared"]["bias"]), 0)
    gamma = _conv3x3(shared, p["gamma"]["kernel"], p["gamma"]["bias"])
    beta = _conv3x3(shared, p["beta"]["kernel"], p["beta"]["bias"])
    x64 = x.astype(np.float64)
    normed = (x64 - x64.mean(axis=(0, 1, 2))) / np.sqrt(x64.var(axis=(0, 1, 2)) + 1e-5)
    np.testing.assert_allclose(got, normed * (1 + gamma) + beta, rtol=1e-4, atol=1e-4)


def test_resize_nearest_follows_pytorch():
    import torch

    x = np.arange(2 * 7 * 5, dtype=np.float32).reshape(1, 7, 5, 2)
    expected = torch.nn.functional.interpolate(torch.from_numpy(x).permute(0, 3, 1, 2), size=(3, 9), mode="nearest")
    np.testing.assert_array_equal(resize_nearest(jnp.asarray(x), 3, 9), expected.permute(0, 2, 3, 1).numpy())


def _inputs(rng, b=2, h=16, w=24, classes=3):
    image = rng.normal(size=(b, h, w, 3)).astype(np.float32)
    return {"images": image, "resynthesis": rng.normal(size=(b, h, w, 3)).astype(np.float32),
            "semantic": rng.integers(0, classes, (b, h, w)).astype(np.int32),
            "semantic_depth": np.where(rng.random((b, h, w)) < 0.1, 255, rng.integers(0, classes, (b, h, w))),
            "uncertainty": rng.random((b, h, w, 2)).astype(np.float32)}


def test_dissimilarity_net_shapes_inputs_and_compiles_once():
    rng = np.random.default_rng(0)
    inputs = _inputs(rng)
    model = DissimilarityNet(3, width=1 / 16)
    variables = random_variables(0, model.init, **inputs)  # NumPy draws: an eager init compiles for seconds

    @jax.jit
    @chex.assert_max_traces(n=1)
    def forward(v, kw):
        return model.apply(v, **kw)["logits"]

    logits = forward(variables, inputs)
    assert logits.shape == (2, 16, 24, 2) and logits.dtype == jnp.float32
    other = dict(inputs, uncertainty=inputs["uncertainty"][::-1].copy())
    assert not np.allclose(forward(variables, other), logits)  # the assistant maps are read
    prob = anomaly_probability(logits)
    assert prob.shape == (2, 16, 24) and np.all((prob >= 0) & (prob <= 1))

    plain = DissimilarityNet(3, uncertainty_channels=0, use_depth=False, width=1 / 16)
    assert plain.extra_inputs == ("resynthesis", "semantic")
    v = jax.eval_shape(plain.init, jax.random.key(0), inputs["images"], inputs["resynthesis"], inputs["semantic"])
    assert "prior_encoder" not in v["params"] and "depth_encoder" not in v["params"]
    with pytest.raises(ValueError, match="divisible by 8"):
        model.init(jax.random.key(0), **_inputs(rng, h=12))
    with pytest.raises(ValueError, match="uncertainty"):
        model.init(jax.random.key(0), **dict(inputs, uncertainty=inputs["uncertainty"][..., :1]))


def test_dissimilarity_net_fits_one_batch_through_the_train_loop(tmp_path):
    from jaxanom.train.segmenter import TrainConfig, train
    from jaxanom.train.optim import OptimConfig

    rng = np.random.default_rng(1)
    inputs = _inputs(rng, b=4, h=16, w=16)
    # anomaly where the resynthesis differs from the image (a square per example), void border ignored
    label = np.zeros((4, 16, 16), np.int32)
    for i in range(4):
        top, left = rng.integers(2, 9, 2)
        label[i, top:top + 5, left:left + 5] = 1
    inputs["resynthesis"] = np.where(label[..., None] == 1, -inputs["images"], inputs["images"])
    label[:, 0] = 255
    batch = {"image": inputs.pop("images"), "label": label, **inputs}
    model = DissimilarityNet(3, width=1 / 16)
    config = TrainConfig(str(tmp_path), steps=40, save_every=1000, progress=False,
                         optim=OptimConfig(name="adamw", lr=3e-3, weight_decay=0.0))
    kw = {k: batch[k] for k in model.extra_inputs}
    # NumPy-drawn start (an init compiles for seconds; the train loop's own init is tested in test_train_segmenter.py)
    state = train(config, model, iter([batch] * 40), variables=random_variables(1, model.init, batch["image"], **kw))
    # jitted: one compile of the forward instead of one per primitive
    prob = np.asarray(anomaly_probability(jax.jit(model.apply)(state.variables, batch["image"], **kw)["logits"]))
    valid = label != 255
    assert ((prob > 0.5) == (label == 1))[valid].mean() > 0.95


@pytest.fixture(scope="module")
def tiny_dissimilarity():
    """A tiny DissimilarityNet at initialisation, its inputs and a jitted forward."""
    inputs = _inputs(np.random.default_rng(7))
    model = DissimilarityNet(3, width=1 / 16)
    # Flax's initialisation drawn by NumPy (kernels of variance 1 / fan-in, zero biases and running
    # means, unit running variances: the net has no other variables) without compiling init
    variables = random_variables(3, model.init, **inputs)
    forward = jax.jit(lambda v, kw: model.apply(v, **kw)["logits"])
    return variables, inputs, forward


def _changes(forward, variables, inputs, **replaced) -> float:
    """max |logits(inputs with ``replaced``) - logits(inputs)|."""
    return float(np.max(np.abs(forward(variables, dict(inputs, **replaced)) - forward(variables, inputs))))


@pytest.mark.parametrize("zero_prior", [False, True])
def test_output_depends_on_image_resynthesis_and_depth_at_initialisation(tiny_dissimilarity, zero_prior):
    # SynBoost concatenates the correlation after the prior product, so even with E2(u) = 0 (u = 0
    # at initialisation, zero biases) the image and the resynthesis reach the decoder
    variables, inputs, forward = tiny_dissimilarity
    if zero_prior:
        inputs = dict(inputs, uncertainty=np.zeros_like(inputs["uncertainty"]))
    flipped = {name: inputs[name][:, ::-1].copy() for name in ("images", "resynthesis", "semantic_depth")}
    assert _changes(forward, variables, inputs, images=flipped["images"]) > 1e-6
    assert _changes(forward, variables, inputs, resynthesis=flipped["resynthesis"]) > 1e-6
    if not zero_prior:  # Ŝ_D enters through the product with E2(u): its encoder's output must be used
        assert _changes(forward, variables, inputs, semantic_depth=flipped["semantic_depth"]) > 1e-6


def test_assistant_maps_multiply_the_fused_features(tiny_dissimilarity):
    # h_l ⊙ E2_l(u): with every fusion conv zeroed h_l = 0, so u can no longer change the output
    # (a sum h_l + E2_l(u) would still pass u on); with the fusion intact it does
    variables, inputs, forward = tiny_dissimilarity
    other_u = inputs["uncertainty"][:, ::-1].copy()
    assert _changes(forward, variables, inputs, uncertainty=other_u) > 1e-6
    params = dict(variables["params"])
    for level in range(4):
        params[f"fuse{level}"] = jax.tree.map(jnp.zeros_like, params[f"fuse{level}"])
    zeroed = dict(variables, params=params)
    assert _changes(forward, zeroed, inputs, uncertainty=other_u) == 0.0
    assert _changes(forward, zeroed, inputs, images=inputs["images"][:, ::-1].copy()) > 1e-6  # correlation path
