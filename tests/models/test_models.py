"""DeepLabV3+ / ResNet / registry: shapes, attention contract, BatchNorm modes, jit/vmap, grads, sizes."""
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.models import (RESNETS, DeepLabV3Plus, ResNet, ResNetSpec, build_model, count_params,
                            model_names)

KEY = jax.random.key(0, impl="rbg")  # cheap to compile on CPU
NUM_CLASSES = 5
IMAGES = np.random.default_rng(0).normal(size=(2, 37, 45, 3)).astype(np.float32)  # odd sizes


def tiny(**kw):
    return build_model("deeplabv3plus_tiny", num_classes=NUM_CLASSES, **kw)


def eval_fn(model):
    return jax.jit(lambda v, x: model.apply(v, x, train=False))


def n_params(tree):
    return sum(math.prod(a.shape) for a in jax.tree.leaves(tree))


def random_variables(model, seed=0, images=IMAGES):
    """Variables of ``model`` filled on the host (no compiled RNG): random kernels, biases and
    BatchNorm statistics, CuDAM's alpha 0 as after ``init``. Shapes come from ``jax.eval_shape``."""
    rng = np.random.default_rng(seed)
    shapes = jax.eval_shape(lambda x: model.init(KEY, x, train=False), images)

    def fill(path, leaf):
        name = path[-1].key
        if name == "kernel":
            return rng.normal(size=leaf.shape).astype(np.float32) * np.sqrt(2 / math.prod(leaf.shape[:-1]))
        if name in ("scale", "var"):
            return rng.uniform(0.5, 1.5, leaf.shape).astype(np.float32)
        if name == "alpha":
            return np.zeros(leaf.shape, np.float32)
        return rng.normal(size=leaf.shape).astype(np.float32) * 0.1

    return jax.tree_util.tree_map_with_path(fill, shapes)


@pytest.fixture(scope="module")
def cudam_vars():
    """Variables of the tiny CuDAM network; they also serve OS 16 (dilation adds no parameters)."""
    return random_variables(tiny(attention="cudam"))


@pytest.fixture(scope="module")
def cudam_eval(cudam_vars):
    """Eval-mode outputs and the batch_stats collection that eval mode hands back."""
    model = tiny(attention="cudam")
    return jax.jit(lambda v, x: model.apply(v, x, train=False, mutable=["batch_stats"]))(
        cudam_vars, IMAGES)


@pytest.fixture(scope="module")
def cudam_out(cudam_eval):
    return cudam_eval[0]


@pytest.fixture(scope="module")
def train_grads(cudam_vars):
    """Gradients (alpha = 0.5) and the batch_stats a train-mode step produces, in one compile."""
    model = tiny(attention="cudam")
    variables = with_alpha(cudam_vars, 0.5)

    def loss(params):
        out, state = model.apply({**variables, "params": params}, IMAGES, train=True,
                                 mutable=["batch_stats"])
        return jnp.mean(out["logits"] ** 2) + jnp.mean(out["attention"]), (out, state)

    # Compiled at optimisation level 0 whatever the suite's setting: there XLA:CPU miscompiled
    # JAX's own max gradient (a float32 count of the maximal channels came out 0: NaN).
    level0 = {"xla_backend_optimization_level": 0}
    grads, (out, state) = jax.jit(jax.grad(loss, has_aux=True), compiler_options=level0)(variables["params"])
    return grads, out, state


def without_cudam(variables):
    return {"params": {k: v for k, v in variables["params"].items() if k != "cudam"},
            "batch_stats": variables["batch_stats"]}


def with_alpha(variables, alpha):
    params = dict(variables["params"])
    params["cudam"] = {**params["cudam"], "alpha": jnp.float32(alpha)}
    return {**variables, "params": params}


# ----------------------------------------------------------------------------- shapes
@pytest.mark.parametrize("output_stride", [8, 16, 32])
@pytest.mark.parametrize("size", [(37, 45), (64, 64), (1, 3)])
def test_resnet_stage_shapes(output_stride, size):
    spec = RESNETS["resnet_tiny"]
    model = ResNet(spec, output_stride)
    x = jax.ShapeDtypeStruct((2, *size, 3), jnp.float32)
    feats = jax.eval_shape(lambda x: model.init_with_output(KEY, x)[0], x)
    strides = {"stem": 4, "layer1": 4, "layer2": 8, "layer3": min(16, output_stride),
               "layer4": output_stride}
    for i, (name, stride) in enumerate(strides.items()):
        channels = spec.width * 2 ** max(i - 1, 0)
        want = (2, -(-size[0] // stride), -(-size[1] // stride), channels)
        assert feats[name].shape == want, name


@pytest.fixture(scope="module")
def os16_surface_out(cudam_vars):
    """Output stride 16 with CuDAM at the surface position (the parameters are the same)."""
    model = tiny(attention="cudam", output_stride=16, attention_position="surface")
    return eval_fn(model)(with_alpha(cudam_vars, 0.7), IMAGES)


@pytest.mark.parametrize("output_stride", [8, 16])
def test_logits_and_attention_shapes_on_odd_input(cudam_out, os16_surface_out, output_stride):
    out = cudam_out if output_stride == 8 else os16_surface_out
    assert set(out) == {"logits", "attention"}
    assert out["logits"].shape == (2, 37, 45, NUM_CLASSES) and out["logits"].dtype == jnp.float32
    # both positions are at stride 4 of 37 x 45: 37 -> 19 -> 10, 45 -> 23 -> 12
    assert out["attention"].shape == (2, 10, 12) and out["attention"].dtype == jnp.float32
    assert np.isfinite(out["logits"]).all()


# ----------------------------------------------------------------------------- attention
@pytest.mark.parametrize("position", ["deep", "surface"])
def test_cudam_attention_sums_to_one_per_image(cudam_out, os16_surface_out, position):
    att = np.asarray((cudam_out if position == "deep" else os16_surface_out)["attention"], np.float64)
    assert (att >= 0).all()
    np.testing.assert_allclose(att.sum((1, 2)), 1.0, rtol=1e-6)
    assert np.ptp(att) > 0  # not a constant map


def test_alpha_zero_equals_plain_network_and_alpha_nonzero_does_not(cudam_vars, cudam_out):
    plain = eval_fn(tiny())(without_cudam(cudam_vars), IMAGES)
    assert float(cudam_vars["params"]["cudam"]["alpha"]) == 0.0
    np.testing.assert_array_equal(cudam_out["logits"], plain["logits"])
    moved = eval_fn(tiny(attention="cudam"))(with_alpha(cudam_vars, 50.0), IMAGES)
    assert np.abs(np.asarray(moved["logits"]) - np.asarray(plain["logits"])).max() > 1e-5


def test_msaam_output_shapes_and_dtypes():
    # MSAAM's values are checked against a NumPy reference in test_nn_attention.py
    model = tiny(attention="msaam", output_stride=16)
    out = jax.eval_shape(lambda x: model.init_with_output(KEY, x, train=False)[0], IMAGES)
    h, w = 3, 3  # ceil(37 / 16), ceil(45 / 16)
    assert out["logits"].shape == (2, 37, 45, NUM_CLASSES) and out["logits"].dtype == jnp.float32
    assert out["branch_weights"].shape == (2, 3) and out["branch_weights"].dtype == jnp.float32
    for name in ("attention", "highlight_scale", "highlight_spatial", "highlight_channel",
                 "highlight_combined"):
        assert out[name].shape == (2, h, w) and out[name].dtype == jnp.float32, name


# ----------------------------------------------------------------------------- BatchNorm, jit, vmap, grads
def test_batchnorm_statistics_change_in_train_mode_only(cudam_vars, cudam_eval, train_grads):
    _, train_out, train_state = train_grads
    changed = jax.tree.map(lambda a, b: bool(np.any(np.asarray(a) != np.asarray(b))),
                           train_state["batch_stats"], cudam_vars["batch_stats"])
    assert all(jax.tree.leaves(changed))
    eval_out, eval_state = cudam_eval
    jax.tree.map(np.testing.assert_array_equal, eval_state["batch_stats"], cudam_vars["batch_stats"])
    assert not np.allclose(train_out["logits"], eval_out["logits"])  # batch vs running statistics


def test_vmap_over_single_examples_agrees_with_batched_jit(cudam_vars, cudam_out):
    # float32 convolutions may sum in another order for another batch size: tolerance ~1e-6
    model = tiny(attention="cudam")
    single = jax.jit(jax.vmap(lambda x: model.apply(cudam_vars, x[None], train=False)))(IMAGES)
    for name in ("logits", "attention"):
        scale = np.abs(np.asarray(cudam_out[name])).max()
        np.testing.assert_allclose(single[name][:, 0], cudam_out[name], rtol=1e-5, atol=1e-6 * scale)


def test_gradients_are_finite(train_grads):
    grads = train_grads[0]
    assert all(np.isfinite(g).all() for g in jax.tree.leaves(grads))
    assert float(grads["cudam"]["alpha"]) != 0.0
    assert np.abs(grads["cudam"]["attention_conv"]["kernel"]).max() > 0
    assert np.abs(grads["backbone"]["stem"]["conv"]["kernel"]).max() > 0


def test_bfloat16_compute_keeps_float32_params_and_outputs(cudam_vars, cudam_out):
    model = tiny(attention="cudam", dtype=jnp.bfloat16)
    shapes = jax.eval_shape(lambda x: model.init(KEY, x, train=False), IMAGES)
    assert set(shapes) == {"params", "batch_stats"}
    assert all(a.dtype == jnp.float32 for a in jax.tree.leaves(shapes))
    out = eval_fn(model)(cudam_vars, IMAGES)
    assert out["logits"].dtype == jnp.float32 and out["attention"].dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(out["attention"]).sum((1, 2)), 1.0, rtol=1e-5)
    ref = np.asarray(cudam_out["logits"])
    assert np.abs(np.asarray(out["logits"]) - ref).max() < 0.1 * np.abs(ref).max()
    assert np.abs(np.asarray(out["logits"]) - ref).max() > 0  # it did compute in bfloat16


# ----------------------------------------------------------------------------- parameter counts
def conv_bn(cin, cout, k):
    return k * k * cin * cout + 2 * cout


def basic_block(cin, cout):
    shortcut = conv_bn(cin, cout, 1) if cin != cout else 0
    return conv_bn(cin, cout, 3) + conv_bn(cout, cout, 3) + shortcut


def test_tiny_parameter_counts_match_hand_formulas():
    w, aspp, low, dec, c = 8, 16, 8, 16, NUM_CLASSES
    backbone = conv_bn(3, w, 7) + sum(basic_block(w * 2 ** max(i - 1, 0), w * 2**i) for i in range(4))
    c4 = 8 * w
    head = (conv_bn(c4, aspp, 1) + 3 * conv_bn(c4, aspp, 3) + conv_bn(c4, aspp, 1)  # ASPP branches
            + conv_bn(5 * aspp, aspp, 1) + conv_bn(w, low, 1)                       # projections
            + conv_bn(aspp + low, dec, 3) + conv_bn(dec, dec, 3) + dec * c + c)     # decoder
    assert count_params(tiny()) == backbone + head
    cudam = 7 * 7 * 2 + 1 + (w + 2 * w + dec) * dec + dec + 1  # Eq. 1 conv, Eq. 2 conv, alpha
    assert count_params(tiny(attention="cudam")) == backbone + head + cudam
    cin, inner, hidden, gru = c4, c4 // 8, c4 // 16, 64
    msaam = (cin * 4 + 4 + 4                                 # scale convs (+bias), level weights
             + 3 * (cin * inner + inner) + 49 * inner + 1   # theta, phi, g; 7x7 conv
             + cin * hidden + hidden * hidden + hidden * cin + cin  # channel W1, W2, W3 + b3
             + 3 * cin * gru + 6 * gru * gru + 4 * gru + 3 * gru + 3)  # GRU input, cell, W_h
    assert count_params(tiny(attention="msaam")) == backbone + head + msaam


def test_small_preset_is_resnet18_at_a_quarter_width_with_a_64_channel_head():
    w, aspp, low, dec, c = 16, 64, 24, 64, NUM_CLASSES
    stages = [(w, w), (w, 2 * w), (2 * w, 4 * w), (4 * w, 8 * w)]
    backbone = conv_bn(3, w, 7) + sum(basic_block(cin, cout) + basic_block(cout, cout) for cin, cout in stages)
    c4 = 8 * w
    head = (conv_bn(c4, aspp, 1) + 3 * conv_bn(c4, aspp, 3) + conv_bn(c4, aspp, 1)
            + conv_bn(5 * aspp, aspp, 1) + conv_bn(w, low, 1)
            + conv_bn(aspp + low, dec, 3) + conv_bn(dec, dec, 3) + dec * c + c)
    assert count_params(build_model("deeplabv3plus_small", num_classes=c)) == backbone + head


def test_deep_stem_shapes_and_parameter_count():
    spec = RESNETS["resnet_tiny"]
    deep = ResNetSpec(spec.stage_sizes, spec.bottleneck, spec.width, deep_stem=True)
    x = jax.ShapeDtypeStruct((2, 37, 45, 3), jnp.float32)
    params, feats = {}, {}
    for name, s in (("plain", spec), ("deep", deep)):
        feats[name], variables = jax.eval_shape(lambda x: ResNet(s, 8).init_with_output(KEY, x), x)
        params[name] = n_params(variables["params"])
    w = spec.width
    assert params["deep"] - params["plain"] == (
        conv_bn(3, w // 2, 3) + conv_bn(w // 2, w // 2, 3) + conv_bn(w // 2, w, 3) - conv_bn(3, w, 7))
    for key in feats["plain"]:
        assert feats["deep"][key].shape == feats["plain"][key].shape, key


@pytest.mark.parametrize("name, want", [
    # torchvision's resnet18 / 50 totals (11,689,512 / 25,557,032) minus the ImageNet
    # classifier (512*1000+1000 / 2048*1000+1000); resnet101 is checked below
    ("resnet18", 11_176_512), ("resnet50", 23_508_032),
])
def test_resnet_parameter_counts_match_torchvision(name, want):
    x = jax.ShapeDtypeStruct((1, 32, 32, 3), jnp.float32)
    shapes = jax.eval_shape(lambda x: ResNet(RESNETS[name], 8).init(KEY, x), x)
    assert n_params(shapes["params"]) == want


def test_paper_configuration_parameter_counts():
    """R101, OS 8, CuDAM deep: one eval_shape trace, no parameters allocated."""
    model = build_model("deeplabv3plus_r101", num_classes=19, output_stride=8, attention="cudam")
    params = jax.eval_shape(lambda x: model.init(KEY, x, train=False),
                            jax.ShapeDtypeStruct((1, 32, 32, 3), jnp.float32))["params"]
    # torchvision's resnet101: 44,549,160 parameters minus its classifier (2048*1000+1000)
    assert n_params(params["backbone"]) == 42_500_160
    # layer1 (256) + layer2 (512) + decoder (256) channels -> 256, plus the 7x7 conv and alpha
    assert n_params(params["cudam"]) == 7 * 7 * 2 + 1 + (256 + 512 + 256) * 256 + 256 + 1 == 262_500
    assert count_params(model) == n_params(params)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("kwargs, match", [
    ({"backbone": "resnet7"}, "backbone"),
    ({"output_stride": 32}, "output_stride"),
    ({"attention": "cbam"}, "attention"),
    ({"attention_position": "middle"}, "attention_position"),
    ({"num_classes": 0}, "num_classes"),
])
def test_bad_configuration_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DeepLabV3Plus(**{"num_classes": 3, **kwargs})


@pytest.mark.parametrize("shape, dtype", [((37, 45, 3), np.float32), ((1, 8, 8, 4), np.float32),
                                          ((1, 8, 8, 3), np.uint8)])
def test_bad_images_raise(shape, dtype):
    with pytest.raises(ValueError, match="images"):
        jax.eval_shape(lambda x: tiny().init(KEY, x), jax.ShapeDtypeStruct(shape, dtype))


def test_registry_names_and_unknown_name():
    assert {"deeplabv3plus_r18", "deeplabv3plus_r50", "deeplabv3plus_r101",
            "deeplabv3plus_tiny", "deeplabv3plus_small"} <= set(model_names())
    model = build_model("deeplabv3plus_r101", num_classes=19, attention="cudam")
    assert (model.backbone, model.output_stride, model.attention) == ("resnet101", 8, "cudam")
    with pytest.raises(ValueError, match="name"):
        build_model("deeplabv3plus_r152")
