"""SML with scarce class statistics (issue 11): statistics fitted on 8, 32 and 256 training frames,
finalised under each policy of ``jaxanom.sml.stats_finalize`` (``none``: the original, classes with
< 2 pixels pooled; ``min_count``: classes under 10 000 pixels pooled; ``shrink``: shrinkage toward
the pooled statistics with a prior of 10 000 pixels), SML (Eq. 5 alone, and with boundary
suppression + smoothing) against max logit on the same plain network, per seed.

    python -m experiments --only sml_scarce_stats
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from experiments.common import (HERE, RUNS, Finding, Scale, _batches, _thin, anomaly_source, improves, over_seeds,
                                plain, trained, write_table)
from jaxanom.app import methods as scoring
from jaxanom import sml
from jaxanom.app.evaluate import class_statistics, predictions, predictor, segmentation_results
from jaxanom.app.experiment import frames
from jaxanom.metrics import AnomalyMetricAccumulator, pr_curve, roc_curve

NAME = "sml_scarce_stats"
TITLE = "SML with scarce class statistics: policies x statistics frames"
STATS_FRAMES = (8, 32, 256)
POLICIES = {"none": dict(policy="none", missing="pooled"), "min_count": dict(policy="min_count", min_count=10_000),
            "shrink": dict(policy="shrink", strength=10_000)}
SCORES = ("sml", "sml_post")


def label(score: str, policy: str | None = None, count: int | None = None) -> str:
    return score if policy is None else f"{score}, {policy}, {count} frames"


def seed_values(scale: Scale, runs: Path, log: Callable) -> tuple[dict, dict, dict]:
    """One seed: ``(values[label], curves[label], scarce[count] = classes under 10 000 pixels)``."""
    net = plain(scale)
    e = net.experiment
    predict = predictor(net.module(), trained(net, runs, log))
    outputs = [{"logits": np.asarray(o["logits"]), "label": np.asarray(o["label"])}
               for o in predictions(predict, _batches(anomaly_source(scale, e), e.batch_size))]
    miou = segmentation_results(predictions(predict, _batches(frames(e, "val", scale.val_frames), e.batch_size)),
                                e.num_classes)["miou"]
    finals, scarce = {}, {}
    for count in STATS_FRAMES:
        stats = class_statistics(predict, _batches(frames(e, "train", count), e.batch_size))
        scarce[count] = int((np.asarray(stats.count) < 10_000).sum())
        for policy, options in POLICIES.items():
            finals[(policy, count)] = sml.stats_finalize(stats, **options)
    runs_of = {label("max_logit"): ("max_logit", None), label("max_logit_post"): ("max_logit_post", None)}
    runs_of.update({label(s, p, c): (s, finals[(p, c)]) for s in SCORES for (p, c) in finals})
    values, curves = {}, {}
    for name, (score, stats) in runs_of.items():
        accumulator, kept = AnomalyMetricAccumulator(), []
        for out in outputs:
            result = np.asarray(scoring.score_batch(score, out["logits"], stats=stats))
            accumulator.update(result, out["label"])
            kept.append((result.ravel(), out["label"].ravel()))
        m = accumulator.compute()
        values[name] = {"ap": 100 * m["ap"], "auroc": 100 * m["auroc"], "fpr95": 100 * m["fpr_at_tpr"],
                        "miou": 100 * miou, "network": net.key, "score": score}
        scores, labels = (np.concatenate(x) for x in zip(*kept))
        fpr, tpr, _ = roc_curve(scores, labels)
        precision, recall, _ = pr_curve(scores, labels)
        curves[name] = {"roc": _thin(fpr, tpr), "pr": _thin(recall, precision)}
    log(f"  {NAME} seed {scale.seed}: classes under 10k pixels {scarce}")
    return values, curves, scarce


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
    scales, values, curves, scarce = over_seeds(seed_values, scale, seeds, runs, log)
    counts = ", ".join(f"{c} frames: {[x[c] for x in scarce]}" for c in STATS_FRAMES)
    description = f"{description} Classes under 10 000 predicted pixels, per seed: {counts}."
    networks = {plain(s).key: plain(s).to_dict() for s in scales}
    return write_table(NAME, TITLE, values, curves, findings, scales, networks, out_dir,
                       description.strip())


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
