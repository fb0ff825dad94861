"""Numeric options traced under jax.jit / jax.vmap over a grid equal the per-value loop; a static
option traced is refused in one line."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom import method_registry, scores, sml
from jaxanom.cudam.score import cudam_score
from jaxanom.errors import InputError

rng = np.random.default_rng(0)
LOGITS = (rng.normal(size=(2, 24, 32, 5)) * 3).astype(np.float32)
MEAN, STD = rng.normal(size=5).astype(np.float32), rng.uniform(0.5, 2, 5).astype(np.float32)
PREDICTION = LOGITS.argmax(-1).astype(np.int32)
SIGMAS = jnp.linspace(0.5, 4.0, 8)


def bits(x):
    return np.asarray(x).view(np.uint32)


@pytest.mark.parametrize("function", [
    lambda s: sml.sml_score_batch(LOGITS, MEAN, STD, sigma=s),
    lambda s: sml.sml_score(LOGITS[0], MEAN, STD, sigma=s, suppress=False),
    lambda s: sml.postprocess_batch(LOGITS[..., 0], PREDICTION, sigma=s),
    lambda s: sml.dilated_smoothing(LOGITS[0, ..., 0], sigma=s, kernel_size=5, dilation=2),
], ids=["sml_score_batch", "sml_score", "postprocess_batch", "dilated_smoothing"])
def test_smoothing_sigma_over_a_grid_equals_the_loop(function):
    grid = np.asarray(jax.jit(jax.vmap(function))(SIGMAS))
    traced = np.stack([jax.jit(function)(s) for s in SIGMAS])  # the same kernel, one sigma per call
    np.testing.assert_array_equal(bits(grid), bits(traced))
    # a Python sigma: the kernel rounded from float64 (unchanged numbers); a traced one: within an ulp or two
    concrete = np.stack([function(float(s)) for s in SIGMAS])
    np.testing.assert_allclose(grid, concrete, rtol=0, atol=4 * np.spacing(np.abs(concrete).max()))


def test_smoothing_weights_of_a_traced_sigma_are_the_gaussian_kernel():
    traced = jax.jit(jax.vmap(lambda s: sml.postprocessing.smoothing_weights(7, s)))(SIGMAS)
    for got, sigma in zip(np.asarray(traced), np.asarray(SIGMAS)):
        np.testing.assert_allclose(got, sml.gaussian_kernel_1d(7, float(sigma)), rtol=4e-7)


@pytest.mark.parametrize("function", [
    lambda t: scores.energy_batch(LOGITS, t),
    lambda t: scores.energy(LOGITS[0], t),
    lambda t: cudam_score(LOGITS[..., 0], LOGITS[..., 1] / 100, t),
    lambda t: method_registry.score("cudam", {"logits": LOGITS, "stats": (MEAN, STD),
                                              "attention": LOGITS[..., 2] / 100}, {"cudam_sigma": t}),
], ids=["energy_batch", "energy", "cudam_score", "cudam_method"])
def test_temperatures_and_cudam_sigma_over_a_grid_equal_the_loop(function):
    grid = np.asarray(jax.jit(jax.vmap(function))(SIGMAS))
    loop = np.stack([function(float(s)) for s in SIGMAS])
    # the batched program may fuse the division by T differently: equal within float32 rounding
    np.testing.assert_allclose(grid, loop, rtol=0, atol=8 * np.spacing(np.abs(loop).max()))


@pytest.mark.parametrize("name, function", [
    ("kernel_size", lambda x: sml.sml_score_batch(LOGITS, MEAN, STD, kernel_size=x)),
    ("dilation", lambda x: sml.dilated_smoothing(LOGITS[0, ..., 0], dilation=x)),
    ("width", lambda x: sml.postprocess(LOGITS[0, ..., 0], PREDICTION[0], width=x)),
    ("iterations", lambda x: sml.suppress_boundaries(LOGITS[0, ..., 0], PREDICTION[0], iterations=x)),
    ("suppress", lambda x: sml.sml_score(LOGITS[0], MEAN, STD, suppress=x)),
    ("normalize", lambda x: scores.entropy_batch(LOGITS, normalize=x)),
    ("slic_step", lambda x: method_registry.score("entropy_superpixel", {
        "logits": LOGITS, "image": np.zeros((*LOGITS.shape[:3], 3), np.uint8)}, {"slic_step": x})),
])
def test_a_traced_static_option_is_refused_in_one_line(name, function):
    value = {"suppress": True, "normalize": True}.get(name, 4 if name != "kernel_size" else 7)
    with pytest.raises(InputError) as error:
        jax.jit(function)(value)
    assert error.value.argument == name and "must be static" in str(error.value) and "\n" not in str(error.value)
