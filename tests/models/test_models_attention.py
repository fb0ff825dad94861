"""Attention modules attached to the segmenters (``jaxanom.models.attention``): CuDAM at DeepLabV3+'s
output (the paper's surface position), CuDAM and MSAAM on ERFNet and ESPNet, the registry's checks."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.models import RESNETS, build_model
from test_models import IMAGES, KEY, NUM_CLASSES, random_variables, with_alpha, without_cudam


def test_output_position_shapes_and_parameters():
    model = build_model("deeplabv3plus_tiny", num_classes=NUM_CLASSES, attention="cudam", attention_position="output")
    shapes = jax.eval_shape(lambda x: model.init_with_output(KEY, x, train=False), IMAGES)
    out, variables = shapes
    assert out["logits"].shape == (2, 37, 45, NUM_CLASSES) and out["logits"].dtype == jnp.float32
    assert out["attention"].shape == (2, 37, 45) and out["attention"].dtype == jnp.float32  # input size
    cudam = variables["params"]["cudam"]
    # Eq. 2's 1x1 convolution maps concat(layer1, layer2, logits) to the C logits channels
    width = RESNETS["resnet_tiny"].width  # layer1 has width channels, layer2 2 * width (basic blocks)
    assert cudam["fusion_kernel"].shape == (width + 2 * width + NUM_CLASSES, NUM_CLASSES)


def test_output_position_is_the_plain_network_at_alpha_zero():
    model = build_model("deeplabv3plus_tiny", num_classes=NUM_CLASSES, attention="cudam", attention_position="output")
    plain = build_model("deeplabv3plus_tiny", num_classes=NUM_CLASSES)
    variables = random_variables(model)
    out0 = jax.jit(lambda v, x: model.apply(v, x, train=False))(variables, IMAGES)
    want = jax.jit(lambda v, x: plain.apply(v, x, train=False))(without_cudam(variables), IMAGES)
    np.testing.assert_allclose(out0["logits"], want["logits"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(out0["attention"], np.float64).sum((1, 2)), 1.0, rtol=1e-5)
    out1 = jax.jit(lambda v, x: model.apply(v, x, train=False))(with_alpha(variables, 50.0), IMAGES)
    assert np.abs(np.asarray(out1["logits"]) - np.asarray(want["logits"])).max() > 1e-4


# ----------------------------------------------------------------------------- ERFNet and ESPNet
SMALL = np.random.default_rng(3).uniform(size=(2, 16, 24, 3)).astype(np.float32)  # multiples of 8


@pytest.mark.parametrize("name, attention, low, mid", [
    ("erfnet", "cudam", 64, 128), ("espnet_p1_q1", "cudam", 131, 256), ("erfnet", "msaam", None, None)])
def test_attention_sits_at_the_encoder_output_of_erfnet_and_espnet(name, attention, low, mid):
    model = build_model(name, num_classes=NUM_CLASSES, attention=attention)
    out, variables = jax.eval_shape(lambda x: model.init_with_output(KEY, x, train=False), SMALL)
    assert out["logits"].shape == (2, 16, 24, NUM_CLASSES)
    assert out["attention"].shape == (2, 2, 3) and out["attention"].dtype == jnp.float32  # stride 8
    params = variables["params"][attention]
    if attention == "cudam":  # Eq. 2 fuses the taps (stride 4, stride 8) with the encoder's output
        encoder_channels = 128 if name == "erfnet" else NUM_CLASSES
        assert params["fusion_kernel"].shape == (low + mid + encoder_channels, encoder_channels)
    else:
        assert out["branch_weights"].shape == (2, 3) and params["channel_w3"]["kernel"].shape == (128 // 16, 128)  # back to C = 128


def test_cudam_on_espnet_is_the_plain_network_at_alpha_zero():
    """ESPNet's weights keep their names with a module attached; alpha = 0 (its init) leaves the logits
    bitwise as they were, and a nonzero alpha moves them."""
    model = build_model("espnet_p1_q1", num_classes=NUM_CLASSES, attention="cudam")
    plain = build_model("espnet_p1_q1", num_classes=NUM_CLASSES)
    variables = random_variables(model, images=SMALL)
    apply = jax.jit(lambda m, v, x: m.apply(v, x, train=False), static_argnums=0)
    out0 = apply(model, variables, SMALL)
    np.testing.assert_array_equal(out0["logits"], apply(plain, without_cudam(variables), SMALL)["logits"])
    np.testing.assert_allclose(np.asarray(out0["attention"], np.float64).sum((1, 2)), 1.0, rtol=1e-5)
    moved = apply(model, with_alpha(variables, 1e3), SMALL)["logits"]
    assert np.abs(np.asarray(moved) - np.asarray(out0["logits"])).max() > 1e-4


@pytest.mark.parametrize("kwargs, match", [
    ({"attention": "cbam"}, r"attention: expected None or one of \('cudam', 'msaam'"),
    ({"attention": "cudam", "attention_position": "surface"}, r"attention_position: expected one of \('deep',\)"),
    ({"attention": "cudam", "attention_options": (("temperature", 2.0),)}, r"attention_options: 'cudam' has the "
     r"options \('gate',\), got \['temperature'\]"),
    ({"attention_position": "deep"}, "attention_position: expected None without an attention module"),
    ({"attention_options": (("gate", "paper"),)}, r"attention_options: None has the options \(\), got \[.gate.\]"),
])
def test_bad_attachments_are_refused_naming_the_field(kwargs, match):
    with pytest.raises(ValueError, match=match):
        build_model("erfnet", **kwargs)


def test_an_outside_attention_module_attaches_by_its_registration_alone(monkeypatch):
    """A module registered from outside jaxanom (here a learnt per-channel scale) runs on every
    segmenter that offers one of its positions, with its option, its outputs and its parameters."""
    import flax.linen as nn

    from jaxanom.models import attention as registry

    class Scale(nn.Module):
        init_value: float = 1.0
        dtype: object = jnp.float32

        @nn.compact
        def __call__(self, x):
            scale = self.param("scale", nn.initializers.constant(self.init_value), (x.shape[-1],))
            return x * scale, {"channel_scale": jnp.broadcast_to(scale, x.shape[:1] + scale.shape)}

    registry.attention_names()  # jaxanom's own first
    spec = registry.AttentionModule("scale", Scale, lambda module, x, taps: module(x), positions=("encoder", "deep"),
                                    options={"init_value": 1.0})
    monkeypatch.setitem(registry.ATTENTION_MODULES.entries, "scale", spec)  # registered, and removed after the test
    monkeypatch.setitem(registry.ATTENTION_MODULES.origins, "scale", __name__)
    for name, channels in (("erfnet", 128), ("deeplabv3plus_tiny", 8 * RESNETS["resnet_tiny"].width)):
        model = build_model(name, num_classes=NUM_CLASSES, attention="scale", attention_options=(("init_value", 2.0),))
        out, variables = jax.eval_shape(lambda x: model.init_with_output(KEY, x, train=False), SMALL)
        assert out["channel_scale"].shape == (2, channels) and variables["params"]["scale"]["scale"].shape == (channels,)
    with pytest.raises(ValueError, match="attention module 'scale': already registered"):
        registry.register(dataclasses.replace(spec, positions=("deep",)))
