"""MMF's rows as registered methods (Eqs. 1-2 and 6).

``mmf_raw`` and ``resynthesis``: the dissimilarity map a, with and without the assistant maps A,
D and the RGB-D semantics; ``mmf`` and ``resynthesis_post``: the same through the superpixel
post-processor (Eq. 6) with the road probability from the logits. They read ``mmf_maps``
(``jaxanom.app.mmf_pipeline.MMFPipeline.maps`` computes them): the maps ``"mmf"`` and
``"resynthesis"`` (B, H, W), ``"superpixels"`` (B, H, W) int labels in [0, ``"num_segments"``)
and, if the resynthesis map has its own segmentation, ``"superpixels_resynthesis"``.

``entropy_superpixel`` and ``softmax_distance_superpixel``: Eq. 6 on the segmenter's own
uncertainty (Eqs. 1-2, normalised), with SLIC superpixels (Algorithm 1) of the image at the
logits' resolution and the road probability (class 0, Cityscapes' trainId) from the logits.
Their option ``slic_step`` defaults to ``superpixels.scaled_step`` of the logits' size.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom import superpixels
from jaxanom._validate import check_static
from jaxanom.method_registry import Method, register
from jaxanom.mmf.postprocess import superpixel_score_batch
from jaxanom.mmf.uncertainty import uncertainty_maps_batch

ROAD_CLASS = 0  # Cityscapes trainId of the road: p_j of Eq. 6


def _dissimilarity(source: str, post: bool):
    def score(inputs, options):
        maps = inputs["mmf_maps"]
        anomaly = jnp.asarray(maps[source], jnp.float32)
        if not post:
            return anomaly
        road = jax.nn.softmax(jnp.asarray(inputs["logits"], jnp.float32), axis=-1)[..., maps.get("road_class", 0)]
        labels = maps.get(f"superpixels_{source}", maps["superpixels"])  # a segmentation of this map, if given
        return superpixel_score_batch(anomaly, road, labels, int(maps["num_segments"]))

    return score


def _on_superpixels(uncertainty: str):
    def score(inputs, options):
        logits, images, step = inputs["logits"], inputs["image"], options["slic_step"]
        if np.shape(images)[:3] != np.shape(logits)[:3] or np.shape(images)[3:] != (3,):
            raise ValueError(f"images: expected (B, H, W, 3) matching logits {np.shape(logits)[:3]}, "
                             f"got {np.shape(images)}")
        size = np.shape(logits)[1:3]
        maps = uncertainty_maps_batch(logits, road=ROAD_CLASS)
        labels = superpixels.slic_batch(superpixels.rgb_to_lab(images), step)
        return superpixel_score_batch(maps[uncertainty], maps["road"], labels, superpixels.num_superpixels(size, step))

    return score


def _scaled_step(inputs, options):
    check_static("slic_step", options["slic_step"], "sets the number of superpixels")
    if options["slic_step"] is not None:
        return {**options, "slic_step": int(options["slic_step"])}
    return {**options, "slic_step": superpixels.scaled_step(tuple(np.shape(inputs["logits"])[1:3]))}


for _name, _source, _post, _description in (
        ("mmf_raw", "mmf", False, "MMF's dissimilarity map a, not post-processed; needs an MMF pipeline"),
        ("mmf", "mmf", True, "MMF: dissimilarity map a through the superpixel post-processor (Eq. 6)"),
        ("resynthesis", "resynthesis", False,
         "dissimilarity of the resynthesis alone (no assistant maps A, D, no RGB-D semantics)"),
        ("resynthesis_post", "resynthesis", True, "resynthesis dissimilarity through the post-processor (Eq. 6)")):
    register(Method(_name, frozenset({"logits", "mmf_maps"}), _dissimilarity(_source, _post), _description))
for _name, _uncertainty, _description in (
        ("entropy_superpixel", "entropy", "MMF's post-processor (Eq. 6) on the normalised entropy (Eq. 1), "
         "SLIC superpixels"),
        ("softmax_distance_superpixel", "distance", "MMF's post-processor (Eq. 6) on the softmax distance (Eq. 2), "
         "SLIC superpixels")):
    register(Method(_name, frozenset({"logits", "image"}), _on_superpixels(_uncertainty), _description,
                    defaults={"slic_step": None}, resolve=_scaled_step, types={"slic_step": int | None}))
