"""What the real-data experiments share: the files of the real-data folder (``REALDATA``, set by
``JAXANOM_REALDATA``), the authors' Cityscapes networks (``NETWORKS``: ESPNet and ERFNet), and the
pooled metrics of their frames with bootstrap intervals (``experiments.stats``).

Frames are few (RoadAnomaly21: 10, RoadObstacle21: 30), so every pooled pixel metric comes with a
95% percentile interval from resampling *frames* with replacement (``bootstrap``): a replicate
pools the pixels of the drawn frames (a frame drawn twice counts twice). Replicates use per-frame
histograms of each score over ``stats.NUM_BINS`` bins at the quantiles of its pooled non-void values,
so a replicate costs a matrix product instead of a sort; the point estimates are exact
(``jaxanom.metrics.anomaly_metrics``), and ``binned_metrics`` of all frames is reported beside them
as the binning's check. Methods compared on the same frames are resampled with the same draws
(paired): ``difference`` intervals come from the same replicates. Both networks see the same
frames in the same order, so their rows resampled with the same ``draws`` are paired too.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from experiments.stats import bin_edges, binned_metrics, bootstrap, frame_histograms, interval
from jaxanom.app.scoring import VOID_CHANNEL

HERE = Path(__file__).parent
REALDATA = Path(os.environ.get("JAXANOM_REALDATA", HERE.parent.parent / "shared" / "realdata"))
CHECKPOINT = REALDATA / "espnet" / "espnet_p_2_q_8.pth"
TRAIN_IDS = VOID_CHANNEL  # channels 0..18 of both networks' weights; channel 19 is their extra void class


def require_realdata(*parts: str) -> Path:
    """``REALDATA / parts``, or exit with one line naming where it was looked for."""
    path = REALDATA.joinpath(*parts)
    if not path.exists():
        sys.exit(f"real data not found at {path} (set JAXANOM_REALDATA to the realdata folder)")
    return path


def espnet():
    """``(model, predict)``: the authors' Cityscapes ESPNet and its jitted forward pass on uint8
    RGB batches (``jaxanom.app.evaluate.predictor``: normalised as the weights expect)."""
    from jaxanom.app.evaluate import predictor
    from jaxanom.weights import from_torch, read_state_dict

    model, variables = from_torch(read_state_dict(require_realdata("espnet", CHECKPOINT.name)), "espnet-cityscapes")
    return model, predictor(model, variables)


def erfnet():
    """``(model, predict)``: the ERFNet authors' Cityscapes weights (the int8 redistribution, dequantised)
    and their jitted forward pass on uint8 RGB batches, with the void channel dropped: the authors
    trained it with loss weight 0 (``weight[19] = 0`` in their training script), so it carries no
    signal, and the road-anomaly repositories that evaluate these weights drop it too."""
    from jaxanom.app.evaluate import predictor
    from jaxanom.weights import from_torch, read_state_dict

    model, variables = from_torch(read_state_dict(require_realdata("erfnet", "erfnet_cityscapes_int8.pth")),
                                  "erfnet-cityscapes")
    forward = predictor(model, variables)
    return model, lambda images: {"logits": forward(images)["logits"][..., :TRAIN_IDS]}


# name -> loader () -> (model, predict). Both were trained on Cityscapes at 1024x512 (ESPNet: the
# 2048x1024 frames halved; ERFNet: its training script's default height 512), so the experiments feed
# both the same frames resized to 1024 wide; ESPNet keeps its void channel (docs/decisions/espnet.md).
NETWORKS = {"ESPNet": espnet, "ERFNet": erfnet}


def per_network(run: Callable[[str], object]) -> dict[str, object]:
    """``{network: run(network)}`` for every network of ``NETWORKS``, each in its own spawned process at
    once (a forked JAX process is unsafe): two processes get twice the share of a busy machine. The
    workers end with this process (a killed experiment leaves none behind)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from experiments.jobs import end_with_parent

    with ProcessPoolExecutor(len(NETWORKS), mp_context=multiprocessing.get_context("spawn"),
                             initializer=end_with_parent) as pool:
        return dict(zip(NETWORKS, pool.map(run, NETWORKS)))


def selected_tracks(names: list[str] | None) -> dict[str, Path]:
    """``anomaly_tracks()`` restricted to ``names`` (all when None), or exit naming the unknown ones."""
    tracks = anomaly_tracks()
    unknown = sorted(set(names or ()) - set(tracks))
    if unknown:
        sys.exit(f"--tracks: expected some of {sorted(tracks)}, got {unknown}")
    return {name: root for name, root in tracks.items() if names is None or name in names}


def logits_of(predict, image: np.ndarray) -> np.ndarray:
    """float32 (H, W, C) logits of one uint8 (H, W, 3) image at its own size (multiples of 8)."""
    return np.asarray(predict(image[None])["logits"][0])


# ----------------------------------------------------------------------------- scoring real frames
def anomaly_tracks() -> dict[str, Path]:
    """The SegmentMeIfYouCan validation tracks (RoadObstacle21's labels are void off the road, so
    its pixels are scored in the road region)."""
    return {"RoadAnomaly21": require_realdata("RoadAnomaly21"), "RoadObstacle21": require_realdata("RoadObstacle21")}


def resized(image: np.ndarray, width: int) -> np.ndarray:
    """``image`` resized (area) to ``width`` columns and the height keeping its aspect, a multiple of 8."""
    import cv2

    height = int(round(image.shape[0] * width / image.shape[1] / 8)) * 8
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def score_frames(predict, root: Path, score_maps, log=print, *,
                 width: int | None = None) -> tuple[dict[str, list[np.ndarray]], list[np.ndarray]]:
    """Every frame of a SegmentMeIfYouCan track through the network, at its own size or ``resized`` to
    ``width`` (then each map is resized back bilinearly); ``score_maps(logits (H, W, C)) -> {name: (H, W)
    scores}``. Returns the non-void pixels only: ``(scores[name][frame] float32 (n,), labels[frame]
    uint8 (n,) in {0, 1})``."""
    import cv2

    from jaxanom.data.smiyc import SegmentMeIfYouCan

    frames = SegmentMeIfYouCan(root)
    scores, labels = {}, []
    for i in range(len(frames)):
        frame = frames[i]
        keep = frame["label"] != 255
        labels.append(frame["label"][keep])
        image = frame["image"] if width is None else resized(frame["image"], width)
        for name, value in score_maps(logits_of(predict, image)).items():
            value = np.asarray(value, np.float32)
            if width is not None:
                value = cv2.resize(value, frame["label"].shape[::-1], interpolation=cv2.INTER_LINEAR)
            scores.setdefault(name, []).append(value[keep])
        log(f"  {root.name} {i + 1}/{len(frames)} {frame['name']}")
    return scores, labels


def same_frames(first: list[np.ndarray], second: list[np.ndarray], track: str) -> None:
    """Raise unless two networks' scored pixels are the same frames in the same order (their rows are
    then paired by resampling both with the same draws)."""
    if len(first) != len(second) or not all(np.array_equal(a, b) for a, b in zip(first, second)):
        raise RuntimeError(f"{track}: the networks were scored on different frames or pixels; cannot pair them")


def exact_metrics(scores: list[np.ndarray], labels: list[np.ndarray]) -> dict[str, float]:
    """Pooled AP (step and envelope) and FPR at 95% TPR ("first") over the frames, exactly
    (``jaxanom.metrics.evaluator.PixelAnomaly`` fed one frame at a time)."""
    from jaxanom.metrics.evaluator import PixelAnomaly, run_evaluators

    frames = ({"scores": {"score": s}, "label": l} for s, l in zip(scores, labels))
    m = run_evaluators({"pixels": PixelAnomaly("score", conventions=True)}, frames)["pixels"]
    return {"ap": m["ap"], "ap_envelope": m["ap_conventions"]["envelope"], "fpr_at_tpr": m["fpr_at_tpr"]}


def with_intervals(scores: dict[str, list[np.ndarray]], labels: list[np.ndarray], multiplicities: np.ndarray
                   ) -> tuple[dict[str, dict], dict[str, dict[str, np.ndarray]]]:
    """Per method: exact pooled metrics, the binned ones (the binning's check) and 95% intervals;
    and every method's bootstrap replicates (same draws for all: paired)."""
    table, replicates = {}, {}
    for name, values in scores.items():
        edges = bin_edges(values, labels)
        histograms = frame_histograms(values, labels, edges)
        replicates[name] = bootstrap(histograms, multiplicities)
        binned = binned_metrics(histograms.sum(0))
        table[name] = {**exact_metrics(values, labels), "binned": {k: float(v) for k, v in binned.items()},
                       "interval": {k: interval(v) for k, v in replicates[name].items()}}
    return table, replicates
