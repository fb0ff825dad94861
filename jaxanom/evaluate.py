"""Evaluation drivers: a network over a dataset -> pooled anomaly metrics and segmentation mIoU.

``predictor(model, variables)`` builds the jitted forward pass once. ``anomaly_results``
scores every batch with each method and pools the pixels of the whole dataset, as the
benchmarks do (METHODS.md §6). ``segmentation_results`` sums confusion matrices.
"""
from __future__ import annotations

from typing import Callable, Iterable, Iterator

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom import methods as scoring
from jaxanom.cudam_score import paper_sigma, upsample_attention
from jaxanom.metrics import AnomalyMetricAccumulator, confusion_matrix, miou, per_class_iou, pixel_accuracy
from jaxanom.metrics import pr_curve, restrict_to_roi, roc_curve
from jaxanom.train.step import model_input


def predictor(model, variables) -> Callable[[np.ndarray], dict]:
    """A jitted ``images (B, H, W, 3) (uint8 RGB, or float normalised) -> {"logits" (B, H, W, C), "attention_up" (B, H, W)?}``.

    uint8 images are normalised as ``model`` wants them (``jaxanom.train.step.model_input``).
    The attention map (if the model has one) is upsampled bilinearly to the image size (Eqs. 4, 10);
    ``"attention_positions"`` (a scalar) is then the h * w of the map before upsampling.
    """

    @jax.jit
    def forward(variables, images):
        out = model.apply(variables, model_input(images, model), train=False)
        result = {"logits": out["logits"].astype(jnp.float32)}
        if "attention" in out:
            result["attention_up"] = upsample_attention(out["attention"], images.shape[1:3])
            result["attention_positions"] = jnp.int32(out["attention"].shape[1] * out["attention"].shape[2])
        return result

    return lambda images: forward(variables, jnp.asarray(images))


def predictions(predict: Callable, batches: Iterable[dict]) -> Iterator[dict]:
    """Each batch with the network's outputs added (``"logits"``, maybe ``"attention_up"``)."""
    for batch in batches:
        yield {**batch, **predict(batch["image"])}


def class_statistics(predict: Callable, batches: Iterable[dict]):
    """SML class statistics (Eqs. 3-4, a ``sml.ClassStats``) of the network's logits over ``batches``."""
    from jaxanom import sml

    return sml.fit_stats(out["logits"] for out in predictions(predict, batches))


def anomaly_results(outputs: Iterable[dict], method_names, *, stats=None, cudam_sigma: float | None = None,
                    mode: str = "exact", fpr_convention: str = "first", ap_convention: str = "step",
                    keep_curves: bool = False) -> tuple[dict, dict]:
    """Pooled metrics per method over batches ``{"logits", "label", "attention_up"?, "attention_positions"?,
    "roi"?, "mmf_maps"?}``.

    ``stats``: SML ``(mean, std)``; ``cudam_sigma``: the ensemble weight of Eq. 10, by default
    (None) the paper-equivalent weight for each batch's attention-map size
    (``cudam_score.paper_sigma`` of ``"attention_positions"``). ``metrics["cudam"]["sigma"]``
    lists the distinct sigmas used.
    Returns ``(metrics[name], curves[name])``; ``curves[name] = {"roc": (fpr, tpr), "pr":
    (recall, precision)}`` when ``keep_curves`` (it keeps every score on the host: small sets
    only). ``mode="binned"`` is not offered here because score ranges differ per method.
    """
    accumulators, kept, sigmas = {}, {}, set()
    for batch in outputs:
        names = scoring.check_methods(method_names, have_stats=stats is not None,
                                      have_attention="attention_up" in batch, have_mmf="mmf_maps" in batch)
        labels = np.asarray(batch["label"])
        if "roi" in batch:  # evaluate inside the region of interest only (MMF: the road)
            labels = restrict_to_roi(labels, batch["roi"])
        sigma = cudam_sigma
        if "cudam" in names:
            sigma = paper_sigma(int(batch["attention_positions"])) if sigma is None else float(sigma)
            sigmas.add(sigma)
        for name in names:
            score = scoring.score_batch(name, batch["logits"], stats=stats, attention_up=batch.get("attention_up"),
                                        cudam_sigma=sigma, mmf_maps=batch.get("mmf_maps"))
            accumulators.setdefault(name, AnomalyMetricAccumulator(mode)).update(score, labels)
            if keep_curves:
                kept.setdefault(name, []).append((np.asarray(score).ravel(), labels.ravel()))
    if not accumulators:
        raise ValueError("outputs: expected at least one batch, got none")
    metrics = {name: acc.compute(fpr_convention=fpr_convention, ap_convention=ap_convention)
               for name, acc in accumulators.items()}
    if "cudam" in metrics:
        metrics["cudam"]["sigma"] = sorted(sigmas)
    curves = {}
    for name, parts in kept.items():
        scores, labels = (np.concatenate(x) for x in zip(*parts))
        fpr, tpr, _ = roc_curve(scores, labels)
        precision, recall, _ = pr_curve(scores, labels)
        curves[name] = {"roc": (fpr, tpr), "pr": (recall, precision)}
    return metrics, curves


def segmentation_results(outputs: Iterable[dict], num_classes: int, ignore: int = 255) -> dict:
    """mIoU, pixel accuracy and per-class IoU over batches ``{"logits", "label"}`` (trainIds)."""
    total = np.zeros((num_classes, num_classes), np.int64)
    for batch in outputs:
        prediction = jnp.argmax(batch["logits"], axis=-1)
        total += np.asarray(confusion_matrix(prediction, batch["label"], num_classes, ignore), np.int64)
    return {"miou": miou(total), "pixel_accuracy": pixel_accuracy(total),
            "per_class_iou": per_class_iou(total).tolist()}
