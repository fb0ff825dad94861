"""SML with scarce class statistics (docs/decisions/sml.md): statistics fitted on 8, 32 and 256 training frames,
finalised under each policy of ``jaxanom.sml.stats_finalize`` (``none``: the original, classes with
< 2 pixels pooled; ``min_count``: classes under 10 000 pixels pooled; ``shrink``: shrinkage toward
the pooled statistics with a prior of 10 000 pixels), SML (Eq. 5 alone, and with boundary
suppression + smoothing) against max logit on the same plain network, per seed. Positive control: the
same network with each pixel's logits multiplied by a factor of its predicted class, 1/4 to 4 over the
classes (``common.scaled_logits``), its statistics fitted here on 256 frames of those logits (policy
``none``), where SML must beat max logit: this table's own statistics path then divides the scales out.

    python -m experiments --only sml_scarce_stats
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from experiments.common import (HERE, LOGIT_SCALE_CONTROL, RUNS, Finding, Scale, _batches, _scaled, _thin,
                                anomaly_source, control_scales, frame_confusions, improves, logit_scale_control,
                                over_seeds, paired_replicates, plain, score_histograms, trained, write_table)
from jaxanom import method_registry
from jaxanom import sml
from jaxanom.app.evaluate import class_statistics, predictions, predictor
from jaxanom.app.experiment import frames
from jaxanom.metrics import AnomalyMetricAccumulator, miou, pr_curve, roc_curve

NAME = "sml_scarce_stats"
TITLE = "SML with scarce class statistics: policies x statistics frames"
STATS_FRAMES = (8, 32, 256)
POLICIES = {"none": dict(policy="none", missing="pooled"), "min_count": dict(policy="min_count", min_count=10_000),
            "shrink": dict(policy="shrink", strength=10_000)}
SCORES = ("sml", "sml_post")
CONTROL_FRAMES = 256  # statistics frames of the positive control


def label(score: str, policy: str | None = None, count: int | None = None) -> str:
    return score if policy is None else f"{score}, {policy}, {count} frames"


def seed_values(scale: Scale, runs: Path, log: Callable) -> tuple[dict, dict, dict]:
    """One seed: ``(values[label], curves[label], {"scarce": {count: classes under 10 000 pixels},
    "frames": {label: per-frame histograms and confusion matrices}})`` (``common.table``'s frames)."""
    net = plain(scale)
    e = net.experiment
    predict = predictor(net.module(), trained(net, runs, log))
    control = _scaled(predict, control_scales(e.num_classes))
    outputs, control_outputs = ([{"logits": np.asarray(o["logits"]), "label": np.asarray(o["label"])}
                                 for o in predictions(p, _batches(anomaly_source(scale, e), e.batch_size))]
                                for p in (predict, control))
    confusions = frame_confusions(predictions(predict, _batches(frames(e, "val", scale.val_frames), e.batch_size)),
                                  e.num_classes)
    segmentation = miou(confusions.sum(0))
    finals, scarce = {}, {}
    for count in STATS_FRAMES:
        stats = class_statistics(predict, _batches(frames(e, "train", count), e.batch_size))
        scarce[count] = int((np.asarray(stats.count) < 10_000).sum())
        for policy, options in POLICIES.items():
            finals[(policy, count)] = sml.stats_finalize(stats, **options)
    control_stats = sml.stats_finalize(class_statistics(control, _batches(frames(e, "train", CONTROL_FRAMES),
                                                                          e.batch_size)), **POLICIES["none"])
    runs_of = {label("max_logit"): ("max_logit", None, outputs),
               label("max_logit_post"): ("max_logit_post", None, outputs)}
    runs_of.update({label(s, p, c): (s, finals[(p, c)], outputs) for s in SCORES for (p, c) in finals})
    runs_of.update({LOGIT_SCALE_CONTROL + "max logit": ("max_logit", None, control_outputs),
                    LOGIT_SCALE_CONTROL + "SML": ("sml", control_stats, control_outputs)})
    values, curves, kept_frames = {}, {}, {}
    labels = [frame_label for out in outputs for frame_label in out["label"]]
    for name, (score, stats, scored) in runs_of.items():
        accumulator, per_frame = AnomalyMetricAccumulator(), []
        for out in scored:
            result = np.asarray(method_registry.score(score, {"logits": out["logits"], "stats": stats}))
            accumulator.update(result, out["label"])
            per_frame.extend(result)
        m = accumulator.compute()
        exact = {"ap": 100 * m["ap"], "auroc": 100 * m["auroc"], "fpr95": 100 * m["fpr_at_tpr"]}
        histograms, binned = score_histograms(per_frame, labels)
        values[name] = {**exact, "miou": 100 * segmentation, "network": net.key, "score": score,
                        "binning": max(abs(binned[k] - v) for k, v in exact.items())}
        kept_frames[name] = {"histograms": histograms, "confusion": confusions}
        scores, labels_flat = (np.concatenate([x.ravel() for x in xs]) for xs in (per_frame, labels))
        fpr, tpr, _ = roc_curve(scores, labels_flat)
        precision, recall, _ = pr_curve(scores, labels_flat)
        curves[name] = {"roc": _thin(fpr, tpr), "pr": _thin(recall, precision)}
    log(f"  {NAME} seed {scale.seed}: classes under 10k pixels {scarce}")
    return values, curves, {"scarce": scarce, "frames": kept_frames}


def findings(v: dict) -> list[Finding]:
    out = []
    for count in STATS_FRAMES:
        for policy in POLICIES:
            out.append(improves(v, label("sml", policy, count), "max_logit", ("fpr95", "auroc"),
                                f"SML ({policy}, {count} frames) beats max logit in FPR95 and AUROC"))
    for count in STATS_FRAMES:
        for policy in ("min_count", "shrink"):
            out.append(improves(v, label("sml", policy, count), label("sml", "none", count), ("fpr95",),
                                f"{policy} lowers SML's FPR95 against none with {count} frames"))
    return out


def run(scale: Scale, seeds: int, out_dir: Path = HERE, runs: Path = RUNS, log: Callable = print,
        description: str = "") -> dict:
    """Every seed, aggregated; writes ``sml_scarce_stats.json/.md/_roc.png/_pr.png``."""
    log(f"{NAME}: {TITLE}")
    scales, values, curves, extras = over_seeds(seed_values, scale, seeds, runs, log)
    for label, replicates in paired_replicates([x["frames"] for x in extras]).items():
        values[label]["replicates"] = replicates
    scarce = [x["scarce"] for x in extras]
    counts = ", ".join(f"{c} frames: {[x[c] for x in scarce]}" for c in STATS_FRAMES)
    description = f"{description} Classes under 10 000 predicted pixels, per seed: {counts}."
    networks = {plain(s).key: plain(s).to_dict() for s in scales}
    return write_table(NAME, TITLE, values, curves, findings, scales, networks, out_dir,
                       description.strip(), controls=controls)


def controls(v: dict) -> list[Finding]:
    return [logit_scale_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
