"""Standardized Max Logits (Jung et al., ICCV 2021) as pure JAX functions.

Pipeline: fit per-class max-logit statistics on training logits (``fit_stats`` ->
``stats_finalize``), standardise test logits (``standardized_max_logit``, Eq. 5), suppress
class boundaries (``suppress_boundaries``, Eqs. 6-7), smooth (``dilated_smoothing``, Eq. 8);
``sml_score`` does the whole test-time path. See docs/papers/sml-cudam-msaam.md#standardized-max-logits.
"""
from jaxanom.sml.boundaries import BORDERS, boundary_distance, find_boundaries
from jaxanom.sml.policy import POLICIES, FinalizedStats
from jaxanom.sml.postprocessing import dilated_smoothing, gaussian_kernel_1d, suppress_boundaries
from jaxanom.sml.score import (
    postprocess,
    postprocess_batch,
    sml_score,
    sml_score_batch,
    standardized_max_logit,
)
from jaxanom.sml.stats import (
    ClassStats,
    fit_stats,
    load_stats,
    load_stats_info,
    save_stats,
    stats_finalize,
    stats_finalize_report,
    stats_init,
    stats_merge,
    stats_update,
    stats_update_batch,
)

__all__ = [
    "BORDERS", "ClassStats", "FinalizedStats", "POLICIES", "boundary_distance", "dilated_smoothing", "find_boundaries", "fit_stats",
    "gaussian_kernel_1d", "load_stats", "load_stats_info", "postprocess", "postprocess_batch", "save_stats", "sml_score",
    "sml_score_batch", "standardized_max_logit", "stats_finalize", "stats_finalize_report", "stats_init", "stats_merge",
    "stats_update", "stats_update_batch", "suppress_boundaries",
]
