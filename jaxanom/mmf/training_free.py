"""MMF's parts that need no training, on any network's logits and real frames.

    out = training_free_maps(logits, images)   # logits (B, H, W, C) of any segmenter, images uint8

Nothing here assumes synthetic scenes or a trained MMF part: Eqs. 1-2 (``uncertainty_maps``:
U, D, the road probability and the prediction), SLIC (``segment``) and the post-processor
(Eq. 6) applied to the entropy U (``"entropy_post"``), for the logits of a converted network
(e.g. ESPNet or DeepLabV3+ weights) on Cityscapes-like frames. The dissimilarity rows need the
trained nets of ``mmf.pipeline``.
"""
from __future__ import annotations

import numpy as np

from jaxanom.mmf.postprocess import superpixel_score_batch
from jaxanom.mmf.uncertainty import uncertainty_maps_batch
from jaxanom.superpixels import num_superpixels, rgb_to_lab, scaled_step, slic_batch

SLIC_INPUTS = ("image", "anomaly")


def segment(images: np.ndarray, anomaly: dict[str, np.ndarray], *, step: int | None = None,
            slic_input: str = "image", connectivity: bool = False) -> dict:
    """SLIC labels for Eq. 6: ``{"superpixels" (B, H, W) int32, "num_segments" K}`` of the Lab
    images (B, H, W, 3) uint8, or with ``slic_input="anomaly"`` one entry per name of ``anomaly``
    (maps (B, H, W) in [0, 1], each segmented as one channel scaled to [0, 100], like Lab's L:
    MMF Sec. III-B, Fig. 4). ``step`` None: ``scaled_step`` of the frame (docs/papers/mmf.md#superpixel-step)."""
    if slic_input not in SLIC_INPUTS:
        raise ValueError(f"slic_input: expected one of {SLIC_INPUTS}, got {slic_input!r}")
    step = step or scaled_step(images.shape[1:3])
    run = lambda x: np.asarray(slic_batch(x, step, connectivity=connectivity))  # noqa: E731
    out = {"num_segments": num_superpixels(images.shape[1:3], step)}
    if slic_input == "image":
        out["superpixels"] = run(rgb_to_lab(images))
    else:
        out.update({name: run(100.0 * np.asarray(a, np.float32)[..., None]) for name, a in anomaly.items()})
    return out


def training_free_maps(logits, images, *, road: int = 0, normalize: str = "max", step: int | None = None,
                       slic_input: str = "image", connectivity: bool = False) -> dict[str, np.ndarray]:
    """``entropy`` (U), ``distance`` (D), ``road`` (p_road), ``prediction``, ``superpixels``,
    ``num_segments`` and ``entropy_post`` (Eq. 6 on U) for logits (B, H, W, C) and the frames
    (B, H, W, 3) uint8 they were computed from; the SLIC settings as ``segment``."""
    if np.ndim(images) != 4 or np.shape(images)[:3] != np.shape(logits)[:3] or np.shape(images)[-1] != 3:
        raise ValueError(f"images: expected (B, H, W, 3) with the logits' B, H, W {np.shape(logits)[:3]}, "
                         f"got {np.shape(images)}")
    maps = {k: np.asarray(v) for k, v in uncertainty_maps_batch(logits, road=road, normalize=normalize).items()}
    maps.update(segment(np.asarray(images), {"superpixels": maps["entropy"]}, step=step, slic_input=slic_input,
                        connectivity=connectivity))
    maps["entropy_post"] = np.asarray(superpixel_score_batch(maps["entropy"], maps["road"], maps["superpixels"],
                                                             maps["num_segments"]))
    return maps
