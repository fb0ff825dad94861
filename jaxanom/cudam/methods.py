"""CuDAM's ensemble (Eq. 10) as a registered method: ``sml_post`` plus sigma times the upsampled attention.

The option ``cudam_sigma`` defaults to the weight with the paper's effect on this batch's
attention map (``cudam.score.paper_sigma`` of its h * w positions): 2e4 on the paper's 256 x 512
maps, scaled with the number of positions elsewhere.
"""
from __future__ import annotations

from jaxanom.cudam.score import cudam_score, paper_sigma
from jaxanom.method_registry import Method, register
from jaxanom.sml.score import sml_score_batch


def _score(inputs, options):
    return cudam_score(sml_score_batch(inputs["logits"], *inputs["stats"]), inputs["attention"],
                       options["cudam_sigma"])


def _paper_equivalent_sigma(inputs, options):
    if options["cudam_sigma"] is not None:
        return options
    if inputs.get("attention_positions") is None:
        raise ValueError("attention_positions: the default cudam_sigma is scaled to the attention map's h * w; "
                         "give attention_positions or a cudam_sigma")
    return {**options, "cudam_sigma": paper_sigma(int(inputs["attention_positions"]))}


register(Method("cudam", frozenset({"logits", "stats", "attention"}), _score,
                "CuDAM ensemble (Eq. 10): sml_post + sigma * attention; needs statistics and a CuDAM network",
                defaults={"cudam_sigma": None}, resolve=_paper_equivalent_sigma, types={"cudam_sigma": float | None}))
