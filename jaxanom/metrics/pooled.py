"""A dataset's metrics from lists of frames, folded by the evaluators (``metrics.evaluator``).

``component_metrics`` (exact) and ``smiyc_pixel_metrics`` / ``smiyc_component_metrics`` (the
official SegmentMeIfYouCan kit's convention, ``metrics.smiyc``) take a dataset as two sequences,
(H, W) score maps and their labels in {0, 1, 255} (frames may differ in size), and run
``run_evaluators`` over them one frame at a time: the component metrics at the pooled best-F1
threshold need two passes (the pixels', then the components'). The frame-level rules live in
``metrics.components`` and ``metrics.smiyc``.
"""
from __future__ import annotations

import numpy as np

from jaxanom.metrics.components import check_track
from jaxanom.metrics.evaluator import Components, PixelAnomaly, SmiycPixels, run_evaluators


def component_metrics(scores_per_image, labels_per_image, *, track: str = "anomaly",
                      threshold: float | None = None) -> dict:
    """SMIYC component metrics of a dataset, pooled over its images (``metrics.components``).

    scores_per_image: sequence of float (H, W) maps; labels_per_image: the matching uint8
    (H, W) labels in {0, 1, 255}. ``threshold``: of the mask score >= threshold (default: the
    pooled pixel threshold of best F1, the point of the exact PR curve). Returns
    ``component_summary`` of all components (``siou`` per ground-truth component, ``ppv`` per
    predicted component, as float64 arrays, ``tp``, ``fn``, ``fp``, ``f1`` (11,), ``f1_mean``,
    ...) plus ``threshold`` and ``track``.
    """
    check_track(track)
    frames = _frames(scores_per_image, labels_per_image, "image")
    if bad := [frame["scores"]["scores"].shape[1:] for frame in frames if frame["scores"]["scores"].ndim != 3]:
        raise ValueError(f"scores_per_image: expected (H, W) maps, got shape {bad[0]}")
    if threshold is None:  # the pooled best-F1 pixel threshold: a pass of its own
        threshold = run_evaluators({"pixels": PixelAnomaly("scores")}, frames)["pixels"]["best_f1_threshold"]
    summary = run_evaluators({"components": Components("scores", threshold, track)}, frames)["components"]
    return {"threshold": float(threshold), "track": track, **summary}


def smiyc_pixel_metrics(scores_per_frame, labels_per_frame) -> dict:
    """The kit's pixel metrics of a dataset: ``smiyc.binned_metrics`` of every frame's ``frame_bins``.

    scores_per_frame: sequence of float (H, W) maps; labels_per_frame: the matching (H, W)
    labels in {0, 1, 255}. Frames may differ in size; a frame without non-void pixels adds nothing.
    """
    frames = _frames(scores_per_frame, labels_per_frame, "frame")
    return run_evaluators({"pixels": SmiycPixels("scores")}, frames)["pixels"]


def smiyc_component_metrics(scores_per_frame, labels_per_frame, *, track: str = "anomaly",
                            threshold: float | None = None) -> dict:
    """The kit's component metrics of a dataset (``SegEval-AnomalyTrack`` / ``-ObstacleTrack``):
    ``component_summary`` (``mean_siou``, ``mean_ppv``, ``f1``, ``f1_mean``, ...) of the masks
    ``smiyc.above_threshold`` at ``threshold`` (default: the kit's best-F1 threshold,
    ``smiyc_pixel_metrics``), plus ``threshold`` and ``track``."""
    check_track(track)
    frames = _frames(scores_per_frame, labels_per_frame, "frame")
    if threshold is None:
        threshold = run_evaluators({"pixels": SmiycPixels("scores")}, frames)["pixels"]["best_f1_threshold"]
    summary = run_evaluators({"components": Components("scores", threshold, track, "smiyc")},
                             frames)["components"]
    return {"threshold": float(threshold), "track": track, **summary}


def _frames(scores, labels, kind: str) -> list[dict]:
    """One-frame batches ``{"scores": {"scores": (1, H, W)}, "label": (1, H, W)}`` of the two
    sequences; ValueError naming ``labels_per_<kind>`` unless they pair up (at least one frame)."""
    scores, labels = list(scores), list(labels)
    if len(scores) != len(labels) or not scores:
        raise ValueError(f"labels_per_{kind}: expected one label map per score map (at least one), got "
                         f"{len(labels)} for {len(scores)}")
    return [{"scores": {"scores": np.asarray(one)[None]}, "label": np.asarray(label)[None]}
            for one, label in zip(scores, labels)]
