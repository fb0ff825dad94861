"""SML's rows as registered methods (Jung et al. 2021, Table 3 and Table 7).

``sml`` is the standardized max logit alone (Eq. 5); ``sml_suppress``, ``sml_smooth`` and
``sml_post`` add boundary suppression (Eqs. 6-7), dilated smoothing (Eq. 8) or both;
``msp_post`` and ``max_logit_post`` apply both to MSP and max logit, with the boundaries of the
network's own prediction (Table 7).
"""
from __future__ import annotations

import jax.numpy as jnp

from jaxanom import scores
from jaxanom.method_registry import Method, register
from jaxanom.sml.score import postprocess_batch, sml_score_batch


def _sml(suppress: bool, smooth: bool):
    return lambda inputs, options: sml_score_batch(inputs["logits"], *inputs["stats"], suppress=suppress,
                                                   smooth=smooth)


def _postprocessed(batch_score):
    def score(inputs, options):
        prediction = jnp.argmax(jnp.asarray(inputs["logits"]), axis=-1).astype(jnp.int32)
        return postprocess_batch(batch_score(inputs["logits"]), prediction)

    return score


for _name, _suppress, _smooth, _description in (
        ("sml", False, False, "standardized max logit (SML Eq. 5); needs class statistics"),
        ("sml_suppress", True, False, "standardized max logit with boundary suppression (SML Eqs. 5-7)"),
        ("sml_smooth", False, True, "standardized max logit with dilated smoothing (SML Eqs. 5, 8)"),
        ("sml_post", True, True, "standardized max logit, boundary suppression and dilated smoothing (SML)")):
    register(Method(_name, frozenset({"logits", "stats"}), _sml(_suppress, _smooth), _description))
register(Method("msp_post", frozenset({"logits"}), _postprocessed(scores.msp_batch),
                "MSP with SML's boundary suppression and dilated smoothing (SML Table 7)"))
register(Method("max_logit_post", frozenset({"logits"}), _postprocessed(scores.max_logit_batch),
                "max logit with SML's boundary suppression and dilated smoothing (SML Table 7)"))
