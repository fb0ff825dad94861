"""CuDAM options beyond the paper's text: the scale-free gate (Eq. 3 deviation) and the paper's surface ("output") position."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.models import RESNETS, build_model
from jaxanom.nn import CuDAMAttention
from test_models import IMAGES, KEY, NUM_CLASSES, random_variables, with_alpha, without_cudam
from attention_reference import as_np, cudam_reference


def test_scale_free_gate_is_eq3_with_alpha_times_hw():
    rng = np.random.default_rng(1)
    f_a = rng.normal(size=(2, 5, 7, 4)).astype(np.float32)
    f_low = rng.normal(size=(2, 5, 7, 3)).astype(np.float32)
    f_mid = rng.normal(size=(2, 3, 4, 2)).astype(np.float32)
    module = CuDAMAttention(gate="scale_free")
    params = jax.jit(module.init)(KEY, f_a, f_low, f_mid)["params"]
    params = {**params, "alpha": jnp.float32(0.3)}
    params["attention_conv"] = {**params["attention_conv"], "kernel": params["attention_conv"]["kernel"] * 5}
    features, att = jax.jit(module.apply)({"params": params}, f_a, f_low, f_mid)
    reference = as_np(params)
    reference["alpha"] = 0.3 * 5 * 7  # h * w
    want_f, want_att = cudam_reference(reference, *(x.astype(np.float64) for x in (f_a, f_low, f_mid)))
    np.testing.assert_allclose(att, want_att, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(features, want_f, rtol=1e-5, atol=1e-5)
    # the map averages 1 per position: alpha * mean(h w M) = alpha, at any size
    np.testing.assert_allclose(np.asarray(att).mean((1, 2)) * 35, 1.0, rtol=1e-6)


def test_unknown_gate_is_rejected():
    with pytest.raises(ValueError, match="gate"):
        CuDAMAttention(gate="sigmoid")


def test_output_position_shapes_and_parameters():
    model = build_model("deeplabv3plus_tiny", num_classes=NUM_CLASSES, attention="cudam", cudam_position="output")
    shapes = jax.eval_shape(lambda x: model.init_with_output(KEY, x, train=False), IMAGES)
    out, variables = shapes
    assert out["logits"].shape == (2, 37, 45, NUM_CLASSES) and out["logits"].dtype == jnp.float32
    assert out["attention"].shape == (2, 37, 45) and out["attention"].dtype == jnp.float32  # input size
    cudam = variables["params"]["cudam"]
    # Eq. 2's 1x1 convolution maps concat(layer1, layer2, logits) to the C logits channels
    width = RESNETS["resnet_tiny"].width  # layer1 has width channels, layer2 2 * width (basic blocks)
    assert cudam["fusion_kernel"].shape == (width + 2 * width + NUM_CLASSES, NUM_CLASSES)


def test_output_position_is_the_plain_network_at_alpha_zero():
    model = build_model("deeplabv3plus_tiny", num_classes=NUM_CLASSES, attention="cudam", cudam_position="output")
    plain = build_model("deeplabv3plus_tiny", num_classes=NUM_CLASSES)
    variables = random_variables(model)
    out0 = jax.jit(lambda v, x: model.apply(v, x, train=False))(variables, IMAGES)
    want = jax.jit(lambda v, x: plain.apply(v, x, train=False))(without_cudam(variables), IMAGES)
    np.testing.assert_allclose(out0["logits"], want["logits"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(out0["attention"], np.float64).sum((1, 2)), 1.0, rtol=1e-5)
    out1 = jax.jit(lambda v, x: model.apply(v, x, train=False))(with_alpha(variables, 50.0), IMAGES)
    assert np.abs(np.asarray(out1["logits"]) - np.asarray(want["logits"])).max() > 1e-4
