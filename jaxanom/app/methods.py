"""Anomaly-scoring methods by name: the rows of every results table.

``score_batch(name, logits, ...)`` maps a batch of logits ``(B, H, W, C)`` to scores
``(B, H, W)``, higher = more anomalous. Names:

- ``msp``, ``max_logit``, ``entropy``, ``energy``, ``softmax_distance``: ``jaxanom.scores``;
- ``sml``: standardized max logit alone (SML Eq. 5), needs ``stats = (mean, std)``;
- ``sml_suppress``, ``sml_smooth``, ``sml_post``: with boundary suppression, dilated
  smoothing, or both (SML Table 3);
- ``msp_post``, ``max_logit_post``: suppression + smoothing applied to MSP / max logit
  (SML Table 7), using the network's prediction for the boundaries;
- ``cudam``: the CuDAM ensemble (Eq. 10) of ``sml_post`` and the upsampled attention map;
- ``mmf_raw``, ``resynthesis``: MMF's dissimilarity map a (with / without the assistant maps
  A, D and the RGB-D semantics); ``mmf``, ``resynthesis_post``: the same through MMF's
  superpixel post-processor (Eq. 6), with the road probability from the logits. They read
  ``mmf_maps`` (``jaxanom.app.mmf_pipeline.MMFPipeline.maps`` computes it);
- ``entropy_superpixel``, ``softmax_distance_superpixel``: MMF's post-processor (Eq. 6) on the
  segmenter's own uncertainty (Eqs. 1-2, normalised by log2 C / in [0, 1]), with SLIC
  superpixels (Algorithm 1) of the image at the logits' resolution and the road probability
  (class 0, Cityscapes' trainId) from the logits. They need ``images`` (B, H, W, 3) uint8 RGB.
"""
from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom import scores, sml
from jaxanom.cudam_score import cudam_score

_PLAIN: dict[str, Callable] = {
    "msp": scores.msp_batch,
    "max_logit": scores.max_logit_batch,
    "entropy": scores.entropy_batch,
    "energy": scores.energy_batch,
    "softmax_distance": scores.softmax_distance_batch,
}
_SML_OPTIONS = {
    "sml": dict(suppress=False, smooth=False),
    "sml_suppress": dict(suppress=True, smooth=False),
    "sml_smooth": dict(suppress=False, smooth=True),
    "sml_post": dict(suppress=True, smooth=True),
}
_POSTPROCESSED = {"msp_post": "msp", "max_logit_post": "max_logit"}

# MMF rows: the dissimilarity map each reads, and whether Eq. 6 post-processes it.
_MMF = {"mmf_raw": ("mmf", False), "mmf": ("mmf", True),
        "resynthesis": ("resynthesis", False), "resynthesis_post": ("resynthesis", True)}

# MMF's post-processor (Eq. 6) over the segmenter's uncertainty map (``mmf.uncertainty`` key).
_SUPERPIXEL = {"entropy_superpixel": "entropy", "softmax_distance_superpixel": "distance"}
ROAD_CLASS = 0  # Cityscapes trainId of the road: p_j of Eq. 6

METHODS: tuple[str, ...] = (*_PLAIN, *_SML_OPTIONS, *_POSTPROCESSED, "cudam", *_MMF, *_SUPERPIXEL)
NEEDS_STATS = frozenset({*_SML_OPTIONS, "cudam"})
NEEDS_ATTENTION = frozenset({"cudam"})
NEEDS_MMF = frozenset(_MMF)
NEEDS_IMAGE = frozenset(_SUPERPIXEL)


def check_methods(names, *, have_stats: bool, have_attention: bool, have_mmf: bool = False,
                  have_image: bool = False) -> tuple[str, ...]:
    """Validate a list of method names against what is available; returns them as a tuple."""
    names = tuple(names)
    unknown = [n for n in names if n not in METHODS]
    if unknown or not names:
        raise ValueError(f"methods: expected names from {METHODS}, got {list(names)}")
    if not have_stats and (missing := [n for n in names if n in NEEDS_STATS]):
        raise ValueError(f"methods {missing} need SML class statistics (mean, std); none were given")
    if not have_attention and (missing := [n for n in names if n in NEEDS_ATTENTION]):
        raise ValueError(f"methods {missing} need an attention map; the model has no CuDAM module")
    if not have_mmf and (missing := [n for n in names if n in NEEDS_MMF]):
        raise ValueError(f"methods {missing} need MMF's maps (a trained jaxanom.app.mmf_pipeline); none were given")
    if not have_image and (missing := [n for n in names if n in NEEDS_IMAGE]):
        raise ValueError(f"methods {missing} need the images (for SLIC superpixels); none were given")
    return names


def _superpixel_score(name: str, logits, images, step: int | None) -> jax.Array:
    from jaxanom import superpixels
    from jaxanom.mmf.postprocess import superpixel_score_batch
    from jaxanom.mmf.uncertainty import uncertainty_maps_batch

    if np.shape(images)[:3] != np.shape(logits)[:3] or np.shape(images)[3:] != (3,):
        raise ValueError(f"images: expected (B, H, W, 3) matching logits {np.shape(logits)[:3]}, got {np.shape(images)}")
    height, width = np.shape(logits)[1:3]
    step = superpixels.scaled_step((height, width)) if step is None else int(step)
    maps = uncertainty_maps_batch(logits, road=ROAD_CLASS)
    labels = superpixels.slic_batch(superpixels.rgb_to_lab(images), step)
    return superpixel_score_batch(maps[_SUPERPIXEL[name]], maps["road"], labels,
                                  superpixels.num_superpixels((height, width), step))


def _mmf_score(name: str, logits, maps: dict) -> jax.Array:
    from jaxanom.mmf.postprocess import superpixel_score_batch

    source, post = _MMF[name]
    anomaly = jnp.asarray(maps[source], jnp.float32)
    if not post:
        return anomaly
    road = jax.nn.softmax(jnp.asarray(logits, jnp.float32), axis=-1)[..., maps.get("road_class", 0)]
    labels = maps.get(f"superpixels_{source}", maps["superpixels"])  # a segmentation of this map, if given
    return superpixel_score_batch(anomaly, road, labels, int(maps["num_segments"]))


def score_batch(name: str, logits, *, stats=None, attention_up=None, cudam_sigma: float = 2e4,
                mmf_maps: dict | None = None, images=None, slic_step: int | None = None) -> jax.Array:
    """Scores of method ``name`` for logits ``(B, H, W, C)`` -> float32 ``(B, H, W)``.

    ``stats``: ``(mean, std)`` each ``(C,)`` for the SML methods; ``attention_up``:
    ``(B, H, W)`` attention already upsampled to the logits' size, and ``cudam_sigma`` (Eq. 10),
    for ``cudam``. ``mmf_maps``: ``{"mmf", "resynthesis"}`` dissimilarity maps (B, H, W),
    ``"superpixels"`` (B, H, W) int labels in [0, ``"num_segments"``) for the MMF rows
    (``"superpixels_resynthesis"``, if present, for the resynthesis rows).
    ``images`` (B, H, W, 3) uint8 RGB and ``slic_step`` (default ``superpixels.scaled_step``) for the
    ``*_superpixel`` rows.
    """
    check_methods([name], have_stats=stats is not None, have_attention=attention_up is not None,
                  have_mmf=mmf_maps is not None, have_image=images is not None)
    if name in _SUPERPIXEL:
        return _superpixel_score(name, logits, images, slic_step)
    if name in _MMF:
        return _mmf_score(name, logits, mmf_maps)
    if name in _PLAIN:
        return _PLAIN[name](logits)
    if name in _SML_OPTIONS:
        return sml.sml_score_batch(logits, *stats, **_SML_OPTIONS[name])
    if name in _POSTPROCESSED:
        prediction = jnp.argmax(jnp.asarray(logits), axis=-1).astype(jnp.int32)
        return sml.postprocess_batch(_PLAIN[_POSTPROCESSED[name]](logits), prediction)
    return cudam_score(sml.sml_score_batch(logits, *stats), attention_up, cudam_sigma)
