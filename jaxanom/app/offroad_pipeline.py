"""The three stages of the off-road paper as one pipeline (docs/papers/offroad.md#pipeline).

- S1 ``learn``: patch annotations -> InfoNCE encoder -> GMM (BIC-chosen m) on P^train (the
  anchors plus ``neighbours`` neighbour samples each, docs/papers/offroad.md#training-patches) -> risk bound r_sigma (Eq. 11).
- S2 ``sequence_risk_sweep`` (FLR per frame on a sliding grid, Eqs. 6-13) and ``segment``
  (sliding windows -> Gaussian votes -> optional dense CRF).
- S3 ``active_round``: if the sequence risk Phi^s exceeds the trigger, choose hard frames (Eq.
  16), annotate them, fine-tune on them (as the paper does) and refit the category model on P^train and P^AL.

Array work runs in the jitted pieces (encoder, classify, vote, CRF); this module is host-side
control flow. ``OffroadModel`` keeps what S2 needs; its ``cluster_class`` maps clusters to
reference classes for evaluation only (IoU needs a class per cluster): the majority reference class of the training
patches in each cluster.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_count, check_labels, check_number
from jaxanom.metrics.segmentation import confusion_counts, confusion_scores
from jaxanom.mixture import GaussianMixture, fit_gmm, select_components
from jaxanom.offroad.active import SELECTIONS, select_hard_frames
from jaxanom.offroad.crf import dense_crf_batch
from jaxanom.offroad.encoder import AnnotatedFrames, EncoderConfig, concat_frames, embed, init_encoder, train_encoder
from jaxanom.offroad.patches import neighbour_centers, sliding_centers
from jaxanom.offroad.risk import RISKS, classify_batch, frame_risk_batch, risk_bound, training_risks, vote_batch
from jaxanom.offroad.supervised import classifier_config


@dataclasses.dataclass(frozen=True)
class OffroadConfig:
    """Settings of the three stages (docs/papers/offroad.md#unstated-settings; ``stride`` s_p/4 segments, ``risk_stride``
    s_p/2 sweeps). ``components``: the BIC scan range, extended one count at a time up to
    ``max_components`` while its minimum sits at the top; or a fixed m with ``fixed_components``."""

    encoder: EncoderConfig = EncoderConfig.tiny()
    neighbours: int = 8
    components: tuple[int, ...] = tuple(range(2, 13))
    max_components: int = 24
    fixed_components: int | None = None
    gmm_inits: int = 3
    delta: float = 0.95
    risk: str = "calibrated"
    stride: int = 8
    risk_stride: int = 16
    epsilon: float = 0.5
    trigger: float = 0.5
    budget: int = 20
    gap: int = 5
    selection: str = "dp"
    finetune_fraction: float = 0.25
    replay: bool = False
    crf_iters: int = 5

    def __post_init__(self):
        if not isinstance(self.encoder, EncoderConfig):
            raise ValueError(f"encoder: expected an EncoderConfig, got {type(self.encoder).__name__}")
        if self.fixed_components is None and len(self.components) < 2:
            raise ValueError(f"components: expected at least two counts to scan, got {self.components}")
        for index, count in enumerate(self.components):
            check_count(f"components[{index}]", count)
        if self.fixed_components is not None:
            check_count("fixed_components", self.fixed_components)
        if self.components and max(self.components) > self.max_components:
            raise ValueError(f"max_components: expected >= the scan's top count {max(self.components)}, "
                             f"got {self.max_components}")
        for name in ("max_components", "gmm_inits", "stride", "risk_stride", "budget"):
            check_count(name, getattr(self, name))
        for name in ("neighbours", "gap", "crf_iters"):
            check_count(name, getattr(self, name), minimum=0)
        check_number("delta", self.delta, 0.0, 1.0, open_low=True)
        check_number("epsilon", self.epsilon, 0.0, 1.0)
        check_number("trigger", self.trigger, 0.0, 1.0)
        check_number("finetune_fraction", self.finetune_fraction, 0.0, 1.0, open_low=True)
        if self.risk not in RISKS:
            raise ValueError(f"risk: expected one of {RISKS}, got {self.risk!r}")
        if self.selection not in SELECTIONS:
            raise ValueError(f"selection: expected one of {SELECTIONS}, got {self.selection!r}")
        if not isinstance(self.replay, bool):
            raise ValueError(f"replay: expected true or false, got {self.replay!r}")


@dataclasses.dataclass
class OffroadModel:
    """Encoder parameters, the category model and its risk calibration (S1's output)."""

    params: object
    mixture: GaussianMixture
    r_sigma: float
    train_raw: np.ndarray
    cluster_class: np.ndarray
    bics: dict[int, float]

    @property
    def num_clusters(self) -> int:
        return int(np.shape(self.mixture.means)[0])


def training_patches(key, data: AnnotatedFrames, config: OffroadConfig) -> tuple[np.ndarray, np.ndarray]:
    """P^train (docs/papers/offroad.md#training-patches): centres (F, A (1 + neighbours), 2) of every anchor followed by its
    ``neighbours`` neighbour samples, and whether each is valid (F, A (1 + neighbours))."""
    f, a = data.ids.shape
    size = config.encoder.size
    height, width = data.images.shape[1:3]
    near = neighbour_centers(key, jnp.asarray(data.centers.reshape(-1, 2)), size, config.neighbours, height, width)
    centers = np.concatenate([data.centers.reshape(-1, 1, 2), np.asarray(near)], axis=1).reshape(f, -1, 2)
    return centers, np.repeat(data.valid.reshape(-1), 1 + config.neighbours).reshape(f, -1)


def fit_category_model(key, params, data: AnnotatedFrames, config: OffroadConfig) -> OffroadModel:
    """Embeds P^train and fits the category model on it (``category_model``)."""
    k_near, k_gmm = jax.random.split(key)
    centers, valid = training_patches(k_near, data, config)
    z = embed(params, data.images, centers, config.encoder)[valid]
    reference = np.repeat(data.reference.reshape(-1), 1 + config.neighbours)[valid.reshape(-1)]
    anchor = (np.arange(valid.size) % (1 + config.neighbours) == 0)[valid.reshape(-1)]
    return category_model(k_gmm, params, z, anchor, reference, config)


def category_model(key, params, z: np.ndarray, anchor: np.ndarray, reference: np.ndarray,
                   config: OffroadConfig) -> OffroadModel:
    """GMM and BIC on the anchors (m by the decisive BIC minimum, or ``fixed_components``; anchors only since
    the neighbour samples are near-duplicates of their anchor and would count each anchor 1 +
    ``neighbours`` times in BIC's N), then r_sigma and cluster -> class on all of P^train.
    ``z (N, D)`` P^train's embeddings, ``anchor (N,)`` which are anchors, ``reference (N,)``."""
    z64 = np.asarray(z, np.float64)
    anchors = z64[np.asarray(anchor, bool)]
    if config.fixed_components is not None:
        fit = fit_gmm(key, anchors, config.fixed_components, n_init=config.gmm_inits)
        bics = {}
    else:
        m, fits, bics = select_components(key, anchors, config.components, n_init=config.gmm_inits,
                                          max_count=config.max_components)
        fit = fits[m]
    mixture = GaussianMixture(*(np.asarray(x) for x in fit.mixture))
    raw, risks = training_risks(z64, mixture, risk=config.risk)
    clusters = np.argmin(raw_cluster_distance(z64, mixture), axis=1)
    return OffroadModel(params, mixture, risk_bound(risks, config.delta), raw,
                        majority_class(clusters, reference, len(mixture.weights)), bics)


def raw_cluster_distance(z: np.ndarray, mixture: GaussianMixture) -> np.ndarray:
    """(N, m) ``-log gamma(z; c_k)`` (Eq. 3 without weights), for Eq. 6's k*."""
    from jaxanom.mixture import log_gaussian

    with jax.enable_x64(True):
        return -np.asarray(jax.jit(log_gaussian)(jnp.asarray(z), jnp.asarray(mixture.means), jnp.asarray(mixture.covariances)))


def majority_class(clusters: np.ndarray, reference: np.ndarray, num_clusters: int) -> np.ndarray:
    """(m,) the most frequent reference class per cluster (lowest on ties; -1 for an empty cluster)."""
    check_labels("clusters", clusters, num_clusters)
    check_labels("reference", reference, np.iinfo(np.int64).max)
    out = np.full(num_clusters, -1, np.int64)
    for k in range(num_clusters):
        members = reference[clusters == k]
        if members.size:
            out[k] = np.bincount(members).argmax()
    return out


def learn(key, data: AnnotatedFrames, config: OffroadConfig, *, progress: Callable | None = None) -> OffroadModel:
    """S1: train the encoder from scratch on ``data`` and fit the category model."""
    k_init, k_train, k_fit = jax.random.split(key, 3)
    params, _ = train_encoder(k_train, init_encoder(k_init, config.encoder), data, config.encoder, progress=progress)
    return fit_category_model(k_fit, params, data, config)


def _classify_frames(model: OffroadModel, images: np.ndarray, centers: np.ndarray, config: OffroadConfig):
    tiled = np.broadcast_to(centers, (len(images), *centers.shape))
    z = embed(model.params, images, tiled, config.encoder)
    return classify_batch(z.astype(np.float64), model.mixture, model.r_sigma, model.train_raw, risk=config.risk)


def sequence_risk_sweep(model: OffroadModel, images: np.ndarray, config: OffroadConfig, *, chunk: int = 16,
                        progress: Callable | None = None) -> np.ndarray:
    """FLR (T,) of frames (T, H, W, 3) float [0, 1] on the ``risk_stride`` grid (Eqs. 6-13)."""
    height, width = images.shape[1:3]
    centers = sliding_centers(height, width, config.encoder.size, config.risk_stride)
    starts = range(0, len(images), chunk)
    flr = []
    for start in (starts if progress is None else progress(starts)):
        out = _classify_frames(model, images[start:start + chunk], centers, config)
        flr.append(np.asarray(frame_risk_batch(np.asarray(out.labels), model.num_clusters)))
    return np.concatenate(flr)


def segment(model: OffroadModel, images: np.ndarray, config: OffroadConfig, *, crf: bool = True) -> dict:
    """S2 on frames (B, H, W, 3) float [0, 1]: window labels, votes -> dense labels (m = unknown),
    ``known_labels`` (argmax over the known clusters' votes: never unknown), risk map, and with
    ``crf`` the CRF labels; all host arrays.

    The CRF's probabilities are the normalised votes of the m known clusters (floored at 1e-4):
    it relabels unknown regions from their surroundings and never outputs the unknown label.
    """
    height, width = images.shape[1:3]
    size = config.encoder.size
    centers = sliding_centers(height, width, size, config.stride)
    out = _classify_frames(model, images, centers, config)
    m = model.num_clusters
    voted = vote_batch(centers, np.asarray(out.labels), np.asarray(out.risk, np.float32), patch_size=size,
                       height=height, width=width, num_labels=m + 1)
    result = {"centers": centers, "window_labels": np.asarray(out.labels), "labels": np.asarray(voted.labels),
              "votes": np.asarray(voted.votes), "risk": np.asarray(voted.risk)}
    # the CRF's input without the CRF (argmax over the known clusters' votes; control for "unknown filled")
    result["known_labels"] = np.where(result["labels"] == 255, 255, result["votes"][..., :m].argmax(-1)).astype(np.int32)
    if crf:
        result["crf_labels"] = crf_labels(result["votes"][..., :m], images, config)  # known clusters only (decision)
    return result


def crf_labels(votes: np.ndarray, images: np.ndarray, config: OffroadConfig) -> np.ndarray:
    """(B, H, W) labels of the dense CRF whose probabilities are the normalised ``votes (B, H, W, L)``
    (floored at 1e-4) on ``images (B, H, W, 3)`` in [0, 1]."""
    probs = np.maximum(votes / np.maximum(votes.sum(-1, keepdims=True), 1e-12), 1e-4)
    q = dense_crf_batch(probs / probs.sum(-1, keepdims=True), images, iters=config.crf_iters, reference_width=512)
    return np.asarray(q).argmax(-1).astype(np.int32)


def segment_supervised(params, images: np.ndarray, config: OffroadConfig, classes: int, *, crf: bool = True) -> dict:
    """The supervised patch classifier (``jaxanom.offroad.supervised``) on frames (B, H, W, 3) in [0, 1]:
    each window's argmax class on the ``stride`` grid, voted into ``labels`` (B, H, W) (never unknown),
    with ``crf`` also ``crf_labels`` from the normalised class votes."""
    height, width = images.shape[1:3]
    size = config.encoder.size
    centers = sliding_centers(height, width, size, config.stride)
    logits = embed(params, images, np.broadcast_to(centers, (len(images), *centers.shape)),
                   classifier_config(config.encoder, classes))
    voted = vote_batch(centers, logits.argmax(-1), patch_size=size, height=height, width=width, num_labels=classes)
    result = {"labels": np.asarray(voted.labels), "votes": np.asarray(voted.votes)}
    if crf:
        result["crf_labels"] = crf_labels(result["votes"], images, config)
    return result


def to_classes(labels: np.ndarray, model: OffroadModel, num_classes: int) -> np.ndarray:
    """Cluster labels (unknown = m, void 255) -> reference classes; unknown and classless clusters
    become ``num_classes`` (the always-wrong column of docs/papers/offroad.md#evaluation), void stays 255."""
    check_labels("labels", labels, model.num_clusters + 1, void=255)
    table = np.append(np.where(model.cluster_class >= 0, model.cluster_class, num_classes), num_classes)
    safe = np.where(labels == 255, 0, labels)
    return np.where(labels == 255, 255, table[np.clip(safe, 0, model.num_clusters)]).astype(np.int32)


def segmentation_scores(predicted: np.ndarray, truth: np.ndarray, num_classes: int) -> dict:
    """Pixel accuracy, mIoU and the means of per-class precision, recall and FPR over the classes
    where each is defined (docs/papers/offroad.md#evaluation): ``predicted`` in [0, num_classes] (num_classes = unknown,
    counted wrong), ``truth`` in [0, num_classes) or 255 (ignored). ``confusion``: the
    (num_classes + 1)^2 counts (rows: truth), which ``metrics.confusion_scores(matrix, num_classes)``
    scores (keys ``OFFROAD_SCORES``)."""
    check_labels("predicted", predicted, num_classes + 1, void=255)
    check_labels("truth", truth, num_classes, void=255)
    matrix = np.asarray(confusion_counts(jnp.asarray(np.where(predicted == 255, num_classes, predicted)),
                                         jnp.asarray(truth), num_classes + 1), np.int64)
    scores = confusion_scores(matrix, num_classes)
    return {**{name: float(scores[key]) for name, key in OFFROAD_SCORES.items()}, "confusion": matrix.tolist()}


# The off-road paper's names -> the keys of ``metrics.confusion_scores``.
OFFROAD_SCORES = {"pixel_accuracy": "pixel_accuracy", "miou": "miou", "precision": "mean_precision",
                  "recall": "class_accuracy", "fpr": "mean_fpr"}


def active_round(key, model: OffroadModel, base: AnnotatedFrames, images: np.ndarray,
                 annotate_frames: Callable[[np.ndarray], AnnotatedFrames], config: OffroadConfig, *,
                 flr: np.ndarray | None = None, force: bool = False, progress: Callable | None = None) -> dict:
    """S3: one round on a sequence ``images`` (T, H, W, 3) float [0, 1].

    ``annotate_frames(indices)`` returns the annotations of those frames (a person, or the
    simulator). Triggered when Phi^s > ``trigger`` (or ``force``). Returns ``{"triggered",
    "flr", "sequence_risk", "chosen", "model"}`` (the old model when not triggered).
    """
    from jaxanom.offroad.risk import sequence_risk

    flr = sequence_risk_sweep(model, images, config, progress=progress) if flr is None else flr
    phi = sequence_risk(flr, config.epsilon)
    result = {"flr": flr, "sequence_risk": phi, "triggered": bool(phi > config.trigger or force),
              "chosen": np.zeros(0, np.int64), "model": model}
    if not result["triggered"]:
        return result
    chosen = select_hard_frames(flr, config.budget, config.gap, method=config.selection)
    result.update(chosen=chosen, model=update_model(key, model, base, annotate_frames(chosen), config,
                                                    progress=progress))
    return result


def update_model(key, model: OffroadModel, base: AnnotatedFrames, new: AnnotatedFrames, config: OffroadConfig, *,
                 progress: Callable | None = None) -> OffroadModel:
    """S3's update (docs/papers/offroad.md#active-learning-round): fine-tune on the new annotations ``new`` (with ``base`` too when
    ``replay``) for ``finetune_fraction`` of the initial steps, then refit the category model on
    P^train u P^AL (``base`` and ``new``)."""
    k_train, k_fit = jax.random.split(key)
    params = fine_tune(k_train, model.params, base, new, config, progress=progress)
    return fit_category_model(k_fit, params, concat_frames(base, new), config)


def fine_tune(key, params, base: AnnotatedFrames, new: AnnotatedFrames, config: OffroadConfig, *,
              progress: Callable | None = None):
    """The encoder part of ``update_model``: ``finetune_fraction`` x the initial steps on ``new``
    (``base`` and ``new`` with ``replay``); returns the new parameters."""
    tune_data = concat_frames(base, new) if config.replay else new
    steps = max(1, int(round(config.encoder.steps * config.finetune_fraction)))
    params, _ = train_encoder(key, params, tune_data, config.encoder, steps=steps, progress=progress)
    return params
