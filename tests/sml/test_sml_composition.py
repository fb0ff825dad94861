"""SML's post-processing composes with any method by name ("NAME+post", "+suppress", "+smooth"),
and the registered *_post rows keep their numbers bitwise."""
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom import method_registry, scores
from jaxanom.app.demos.sml_cudam import DEMO_METHODS
from jaxanom.app.scoring import describe, score_all
from jaxanom.cli import main
from jaxanom.sml import postprocess_batch

rng = np.random.default_rng(0)
CLASSES = 19
STATS = (rng.normal(size=CLASSES).astype(np.float32), rng.uniform(0.5, 2, CLASSES).astype(np.float32))
# the registered rows and the composed names that must equal them bitwise
ROWS = {"msp_post": "msp+post", "max_logit_post": "max_logit+post", "sml_post": "sml+post",
        "sml_suppress": "sml+suppress", "sml_smooth": "sml+smooth"}


def bits(x):
    return np.asarray(x).view(np.uint32)


@pytest.mark.parametrize("dtype", [np.float32, np.float16])
def test_every_post_row_equals_the_composed_method_bitwise(dtype):
    logits = (rng.normal(size=(2, 33, 47, CLASSES)) * 4).astype(dtype)
    inputs = {"logits": logits, "stats": STATS}
    assert {n for n in method_registry.names() if n.endswith("_post")} - set(ROWS) == {"resynthesis_post"}  # MMF's Eq. 6
    assert {n for n in DEMO_METHODS if n.endswith("_post")} <= set(ROWS)
    for row, composed in ROWS.items():
        np.testing.assert_array_equal(bits(method_registry.score(row, inputs)),
                                      bits(method_registry.score(composed, inputs)), err_msg=row)
    # msp_post / max_logit_post as they were written before composition: Table 7's rows unchanged
    prediction = jnp.argmax(jnp.asarray(logits), axis=-1).astype(jnp.int32)
    for row, score in (("msp_post", scores.msp_batch), ("max_logit_post", scores.max_logit_batch)):
        np.testing.assert_array_equal(bits(method_registry.score(row, inputs)),
                                      bits(postprocess_batch(score(logits), prediction)), err_msg=row)


def test_any_method_composes_and_posts_chain():
    logits = (rng.normal(size=(1, 20, 24, 4)) * 3).astype(np.float32)
    prediction = logits.argmax(-1).astype(np.int32)
    energy = scores.energy_batch(logits)
    got, used = score_all(["energy+post", "entropy+smooth", "energy+suppress+smooth"], {"logits": logits})
    np.testing.assert_array_equal(got["energy+post"], postprocess_batch(energy, prediction))
    np.testing.assert_array_equal(got["entropy+smooth"],
                                  postprocess_batch(scores.entropy_batch(logits), prediction, suppress=False))
    suppressed = postprocess_batch(energy, prediction, smooth=False)
    np.testing.assert_array_equal(got["energy+suppress+smooth"], postprocess_batch(suppressed, prediction, suppress=False))
    assert used == {"energy+post": {}, "entropy+smooth": {}, "energy+suppress+smooth": {}}
    method = method_registry.get("cudam+smooth")  # options and needs of the base method carry over
    assert method.needs == {"logits", "stats", "attention"} and dict(method.defaults) == {"cudam_sigma": None}
    assert "NAME+post" in describe() and "SML's dilated smoothing" in describe()


def test_unknown_compositions_and_plus_in_a_name_are_refused():
    for name in ("energy+bogus", "bogus+post", "energy+", "+post"):
        with pytest.raises(ValueError, match=r"each may end in \+post, \+suppress, \+smooth"):
            method_registry.get(name)
    with pytest.raises(ValueError, match="need SML class statistics"):
        method_registry.check(["sml+post"], {"logits"})
    with pytest.raises(ValueError, match=r"method name: expected letters.*got 'a\+b'"):
        method_registry.register(method_registry.Method("a+b", frozenset({"logits"}), lambda i, o: 0, "x"))


PLUGIN = """
import jax.numpy as jnp
from jaxanom.method_registry import Method, register

register(Method("margin_test", frozenset({"logits"}),
                lambda inputs, options: -jnp.diff(jnp.sort(jnp.asarray(inputs["logits"]), axis=-1)[..., -2:], axis=-1)[..., 0],
                "a test's plug-in: minus the gap of the two largest logits"))
"""


def test_a_plugin_method_composes_on_the_command_line(tmp_path, monkeypatch):
    (tmp_path / "jaxanom_test_plugin_margin.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(method_registry.METHODS, "entries", dict(method_registry.METHODS.entries))
    monkeypatch.setattr(method_registry.METHODS, "origins", dict(method_registry.METHODS.origins))
    monkeypatch.delitem(sys.modules, "jaxanom_test_plugin_margin", raising=False)
    logits = rng.normal(size=(2, 5, 16, 20)).astype(np.float32)  # NCHW, as the score command reads it
    np.save(tmp_path / "logits.npy", logits)
    out = tmp_path / "out"
    assert main(["score", "--logits", str(tmp_path / "logits.npy"), "--plugin", "jaxanom_test_plugin_margin",
                 "--methods", "margin_test,margin_test+post", "--out", str(out)]) == 0
    plain = np.load(out / "scores" / "margin_test.npy")
    top2 = np.sort(logits.transpose(0, 2, 3, 1), axis=-1)[..., -2:]
    np.testing.assert_allclose(plain, top2[..., 0] - top2[..., 1], rtol=1e-6)
    np.testing.assert_array_equal(np.load(out / "scores" / "margin_test+post.npy"),
                                  postprocess_batch(plain, logits.argmax(1).astype(np.int32)))
    sys.modules.pop("jaxanom_test_plugin_margin", None)
