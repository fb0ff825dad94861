"""SML's rows as registered methods (Jung et al. 2021, Table 3 and Table 7), and its
post-processing as post-processors any method composes with.

``sml`` is the standardized max logit alone (Eq. 5); ``sml_suppress``, ``sml_smooth`` and
``sml_post`` add boundary suppression (Eqs. 6-7), dilated smoothing (Eq. 8) or both.
The post-processors ``post``, ``suppress`` and ``smooth`` apply the same steps to any method's
scores, with the boundaries of the network's own prediction (the logits' argmax; Table 7):
``"energy+post"``, ``"msp+smooth"``. ``msp_post`` and ``max_logit_post`` are ``"msp+post"`` and
``"max_logit+post"`` under their Table 7 names; ``"sml+post"`` equals ``sml_post`` bitwise.
"""
from __future__ import annotations

import jax.numpy as jnp

from jaxanom import scores
from jaxanom.method_registry import Method, Post, register, register_post
from jaxanom.sml.score import postprocess_batch, sml_score_batch


def _sml(suppress: bool, smooth: bool):
    return lambda inputs, options: sml_score_batch(inputs["logits"], *inputs["stats"], suppress=suppress,
                                                   smooth=smooth)


def _postprocessor(suppress: bool, smooth: bool):
    def apply(score, inputs):
        prediction = jnp.argmax(jnp.asarray(inputs["logits"]), axis=-1).astype(jnp.int32)
        return postprocess_batch(score, prediction, suppress=suppress, smooth=smooth)

    return apply


for _name, _suppress, _smooth, _description in (
        ("sml", False, False, "standardized max logit (SML Eq. 5); needs class statistics"),
        ("sml_suppress", True, False, "standardized max logit with boundary suppression (SML Eqs. 5-7)"),
        ("sml_smooth", False, True, "standardized max logit with dilated smoothing (SML Eqs. 5, 8)"),
        ("sml_post", True, True, "standardized max logit, boundary suppression and dilated smoothing (SML)")):
    register(Method(_name, frozenset({"logits", "stats"}), _sml(_suppress, _smooth), _description))

POST = register_post(Post("post", frozenset({"logits"}), _postprocessor(True, True),
                          "SML's boundary suppression and dilated smoothing (Eqs. 6-8)"))
register_post(Post("suppress", frozenset({"logits"}), _postprocessor(True, False),
                   "SML's boundary suppression (Eqs. 6-7)"))
register_post(Post("smooth", frozenset({"logits"}), _postprocessor(False, True), "SML's dilated smoothing (Eq. 8)"))
for _name, _score, _description in (
        ("msp_post", scores.msp_batch, "MSP with SML's boundary suppression and dilated smoothing (SML Table 7)"),
        ("max_logit_post", scores.max_logit_batch,
         "max logit with SML's boundary suppression and dilated smoothing (SML Table 7)")):
    register(Method(_name, frozenset({"logits"}),
                    lambda inputs, options, score=_score: POST.apply(score(inputs["logits"]), inputs), _description))
