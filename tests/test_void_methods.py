"""The void-channel method ``void``: softmax probability of a 20-output network's void channel,
against NumPy; needed where the logits carry that channel, refused where they do not."""
import jax
import numpy as np
import pytest

from jaxanom import method_registry
from jaxanom.app.scoring import inputs_of, provided
from jaxanom.cli import main
from jaxanom.void_methods import void_probability_batch


def numpy_softmax(logits: np.ndarray) -> np.ndarray:
    z = logits.astype(np.float64)
    e = np.exp(z - z.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def awkward_logits(rng, shape=(2, 3, 5, 20)) -> np.ndarray:
    logits = rng.normal(size=shape).astype(np.float32) * 4
    logits[0, 0, 0] = 0.0  # every class tied
    logits[0, 0, 1, :] = -3e4
    logits[0, 0, 1, 19] = 3e4  # void certain, huge values
    logits[0, 0, 2, 3] = 1e4  # void impossible
    logits[1, 2, 4, [2, 19]] = 50.0  # void tied with a class at the top
    return logits


def test_void_probability_matches_numpy():
    logits = awkward_logits(np.random.default_rng(0))
    p = numpy_softmax(logits)
    for channel in (19, 0, 7):
        got = void_probability_batch(logits, channel)
        assert got.dtype == np.float32 and got.shape == (2, 3, 5)
        np.testing.assert_allclose(got, p[..., channel], rtol=1e-5, atol=1e-7)
    got = np.asarray(void_probability_batch(logits, 19))
    assert got[0, 0, 0] == pytest.approx(1 / 20) and got[0, 0, 1] == 1 and got[0, 0, 2] == 0
    assert got[1, 2, 4] == pytest.approx(0.5)
    np.testing.assert_allclose(void_probability_batch(logits.astype(np.float16), 19),
                               numpy_softmax(logits.astype(np.float16))[..., 19], rtol=1e-5, atol=1e-7)


def test_void_probability_under_a_users_jit_and_vmap():
    logits = awkward_logits(np.random.default_rng(1))
    eager = np.asarray(void_probability_batch(logits, 19))
    traced = jax.jit(jax.vmap(lambda x: void_probability_batch(x, 19)))(np.stack([logits, logits[::-1]]))
    np.testing.assert_allclose(traced[0], eager, rtol=1e-6)
    np.testing.assert_allclose(traced[1], eager[::-1], rtol=1e-6)


@pytest.mark.parametrize("logits, channel, message", [
    (np.zeros((2, 3, 20)), 19, "rank 4"),
    (np.zeros((1, 2, 3, 19)), 19, "void_channel: expected a channel of the logits' 19, got 19"),
    (np.zeros((1, 2, 3, 20)), -1, "void_channel"),
    (np.full((1, 2, 3, 20), np.nan), 19, "finite"),
    (np.zeros((1, 2, 3, 20), bool), 19, "real"),
])
def test_bad_input_is_refused(logits, channel, message):
    with pytest.raises(ValueError, match=message):
        void_probability_batch(logits, channel)


def test_the_method_needs_logits_that_keep_the_void_channel():
    logits = awkward_logits(np.random.default_rng(2))
    inputs = inputs_of({"logits": logits})
    assert inputs["void_channel"] == 19
    np.testing.assert_allclose(method_registry.score("void", inputs), numpy_softmax(logits)[..., 19], rtol=1e-5,
                               atol=1e-7)
    assert "void_channel" not in inputs_of({"logits": logits[..., :19]})
    assert method_registry.check(["void", "msp"], provided(classes=20, stats=False)) == ("void", "msp")
    with pytest.raises(ValueError, match=r"methods \['void'\] need the index of a void output"):
        method_registry.check(["msp", "void"], provided(classes=19, stats=False))


def test_score_command_keeps_every_channel_for_the_other_methods(tmp_path, capsys):
    rng = np.random.default_rng(3)
    logits = np.moveaxis(awkward_logits(rng, (2, 21, 23, 20)), -1, 1)  # NCHW, as PyTorch saves ERFNet's outputs
    np.save(tmp_path / "logits.npy", logits)
    out = tmp_path / "out"
    assert main(["score", "--logits", str(tmp_path / "logits.npy"), "--methods", "void,msp", "--out", str(out)]) == 0
    p = numpy_softmax(np.moveaxis(logits, 1, -1))
    np.testing.assert_allclose(np.load(out / "scores" / "void.npy"), p[..., 19], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.load(out / "scores" / "msp.npy"), 1 - p.max(-1), rtol=1e-4, atol=1e-6)

    np.save(tmp_path / "l19.npy", logits[:, :19])
    args = ["--methods", "void", "--out", str(tmp_path / "o")]
    assert main(["score", "--logits", str(tmp_path / "l19.npy"), *args]) == 2
    error = capsys.readouterr().err.strip()
    assert "need the index of a void output" in error and len(error.splitlines()) == 1
