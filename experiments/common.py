"""What every paper-table experiment shares: networks, cached training, evaluation, tables, findings.

An experiment file lists the rows of its table, each a ``Row(label, network, score)``, and the
paper's qualitative findings as functions of the table. ``run_table`` trains every network once
into ``runs/<hash of its configuration>/`` (so experiments with an identical configuration share
it, and an interrupted run resumes), fits the SML class statistics on training frames, scores the
anomaly frames with every score, and writes ``<name>.json``, ``<name>.md``, ``<name>_roc.png`` and
``<name>_pr.png`` beside the experiment file.

Networks are trained with AdamW (lr 2e-3, as ``jaxanom demo``) instead of the papers' SGD (lr 0.01
for tens of thousands of steps), because the budget here is a few hundred steps.

CuDAM's constants are per-pixel magnitudes for attention maps of the paper's size: tau = 5e4 for
a 180 x 180 training map (720 x 720 crops, §IV-D) and sigma = 2e4 for 256 x 512 test maps
(1024 x 2048 frames at stride 4). A map sums to 1, so its values scale as 1 / (h * w); the
defaults here scale tau and sigma by the ratio of map sizes (``matched_tau``, ``matched_sigma``,
through ``jaxanom.cudam_score.equivalent_weight``)
so that ``tau * M_att`` has the paper's magnitude. The paper's literal values are rows of their own
(``cudam_fig6`` trains with tau = 5e4; the score ``cudam`` uses sigma = 2e4).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from jaxanom import methods as scoring
from jaxanom import sml
from jaxanom.cudam_score import PAPER_TEST_POSITIONS, PAPER_TRAIN_POSITIONS, cudam_score, equivalent_weight
from jaxanom.evaluate import class_statistics, predictions, predictor, segmentation_results
from jaxanom.experiment import Experiment, build_network, frames, jsonable, run_training
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.metrics import AnomalyMetricAccumulator, pr_curve, roc_curve
from jaxanom.train.loop import TrainConfig
from jaxanom.train.optim import OptimConfig
from jaxanom.train.step import LossConfig

HERE = Path(__file__).parent
RUNS = HERE / "runs"
PAPER_TAU, PAPER_SIGMA = 5e4, 2e4
ANOMALY_READERS = ("road_anomaly", "smiyc")
# Scores every network gets; "<base>+att" is the CuDAM ensemble (Eq. 10) of <base> with the
# network's attention at the matched sigma, "cudam" the library's (SML + 2e4 * attention).
BASE_SCORES = ("msp", "max_logit", "entropy", "sml", "sml_suppress", "sml_smooth", "sml_post",
               "msp_post", "max_logit_post")
ENSEMBLE_BASES = ("msp", "max_logit", "sml_post")


@dataclasses.dataclass(frozen=True)
class Scale:
    """Sizes and data shared by every experiment; the defaults run all tables in ~20 min on 2 CPU cores.

    ``cityscapes_root``: train on Cityscapes (crops of ``height`` x ``width``) instead of synthetic
    scenes. ``anomaly``: ``"road_anomaly:<root>"`` or ``"smiyc:<track root>"`` to score a real
    anomaly dataset instead of the synthetic ``anomaly_split``.
    """

    train_frames: int = 256
    height: int = 128
    width: int = 256
    batch_size: int = 8
    steps: int = 500
    stats_frames: int = 64
    val_frames: int = 32
    anomaly_frames: int = 64
    anomaly_split: str = "anomaly"
    seed: int = 0
    cityscapes_root: str | None = None
    anomaly: str | None = None

    def __post_init__(self):
        if self.anomaly is not None and self.anomaly.partition(":")[0] not in ANOMALY_READERS:
            raise ValueError(f"anomaly: expected '<reader>:<root>' with reader in {ANOMALY_READERS}, "
                             f"got {self.anomaly!r}")

    @classmethod
    def smoke(cls) -> "Scale":
        """A seconds-long run of the same code (tests)."""
        return cls(train_frames=4, height=64, width=96, batch_size=4, steps=2, stats_frames=2,
                   val_frames=2, anomaly_frames=2)


@dataclasses.dataclass(frozen=True)
class Network:
    """A trainable ``Experiment``, named by the hash of its configuration."""

    experiment: Experiment

    def to_dict(self) -> dict:
        return jsonable(self.experiment)

    @property
    def key(self) -> str:
        """Hash of the configuration: the run folder's name."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:12]

    def module(self):
        return build_network(self.experiment)


@dataclasses.dataclass(frozen=True)
class Row:
    """One line of a table: ``score`` (a ``BASE_SCORES`` name, ``"<base>+att"`` or ``"cudam"``) of ``network``."""

    label: str
    network: Network
    score: str


@dataclasses.dataclass(frozen=True)
class Finding:
    """A qualitative claim of the paper and whether this run reproduces it."""

    claim: str
    holds: bool
    evidence: str


def attention_positions(height: int, width: int) -> int:
    """Positions of CuDAM's map for an ``height`` x ``width`` input (stride 4: ceil(ceil(H/2)/2))."""
    return math.ceil(math.ceil(height / 2) / 2) * math.ceil(math.ceil(width / 2) / 2)


def matched_tau(scale: Scale) -> float:
    """The reward weight whose ``tau * M_att`` matches the paper's tau = 5e4 on 180 x 180 maps."""
    return equivalent_weight(PAPER_TAU, attention_positions(scale.height, scale.width), PAPER_TRAIN_POSITIONS)


def matched_sigma(height: int, width: int) -> float:
    """The ensemble weight matching the paper's sigma = 2e4 on 256 x 512 maps, for ``height`` x ``width`` frames."""
    return equivalent_weight(PAPER_SIGMA, attention_positions(height, width), PAPER_TEST_POSITIONS)


def network(scale: Scale, attention: str | None = None, loss: LossConfig = LossConfig(),
            cudam_position: str = "deep") -> Network:
    """The tiny DeepLabV3+ of every table, trained on ``scale``'s data with ``loss``."""
    data = dict(data="cityscapes", data_root=scale.cityscapes_root) if scale.cityscapes_root else {}
    train = TrainConfig(run_dir="", steps=scale.steps, seed=scale.seed, loss=loss, eval_every=scale.steps,
                        save_every=scale.steps, keep=1, progress=False,
                        optim=OptimConfig(name="adamw", lr=2e-3, weight_decay=1e-4,
                                          warmup_steps=max(1, min(30, scale.steps // 10))))
    experiment = Experiment(model="deeplabv3plus_tiny", attention=attention, train_frames=scale.train_frames,
                            height=scale.height, width=scale.width, crop=(scale.height, scale.width),
                            batch_size=scale.batch_size, cudam_position=cudam_position, train=train, **data)
    return Network(experiment)


def plain(scale: Scale) -> Network:
    """No attention, cross-entropy: the baseline of every table."""
    return network(scale)


def cudam(scale: Scale, position: str = "deep", **loss) -> Network:
    """DeepLabV3+ with CuDAM trained with Eq. 8.

    ``loss`` overrides ``LossConfig`` fields; tau defaults to ``matched_tau``.
    """
    config = LossConfig(method="cudam", **{"tau": matched_tau(scale), **loss})
    return network(scale, "cudam", config, position)


def msaam(scale: Scale) -> Network:
    """DeepLabV3+ with MSAAM trained with its loss (Eq. 7)."""
    return network(scale, "msaam", LossConfig(method="msaam"))


# ---------------------------------------------------------------- training


def trained(net: Network, runs: Path, log: Callable = print) -> dict:
    """The network's final variables: trained into ``runs/<key>/``, or restored when already there.

    No validation during training: ``evaluate`` measures mIoU afterwards.
    """
    e = net.experiment
    run_dir = runs / net.key
    done = (run_dir / "checkpoints" / str(e.train.steps)).exists()
    log(f"  network {net.key}: {'restoring' if done else 'training'} {e.attention or 'plain'} "
        f"({e.train.loss.method} loss, {e.train.steps} steps)")
    start = time.perf_counter()
    variables = run_training(e, run_dir, progress=False, validate=False)
    if not done:
        log(f"  trained in {time.perf_counter() - start:.0f} s")
    return variables


# ---------------------------------------------------------------- evaluation


def anomaly_source(scale: Scale, experiment: Experiment):
    """The frames to score: a real dataset when ``scale.anomaly`` names one, else synthetic frames."""
    if scale.anomaly is None:
        return frames(experiment, scale.anomaly_split, scale.anomaly_frames)
    from jaxanom.data import RoadAnomaly, SegmentMeIfYouCan

    reader, _, root = scale.anomaly.partition(":")
    return {"road_anomaly": RoadAnomaly, "smiyc": SegmentMeIfYouCan}[reader](root)


def _batches(source, batch_size: int):
    from jaxanom.data.pipeline import evaluation_batches

    return evaluation_batches(source, batch_size=batch_size)


def _scores(out: dict, stats) -> dict:
    """Every score of one batch of outputs (see ``BASE_SCORES``, ``ENSEMBLE_BASES``)."""
    attention = out.get("attention_up")
    scores = {name: scoring.score_batch(name, out["logits"], stats=stats) for name in BASE_SCORES}
    if attention is not None:
        sigma = matched_sigma(*out["logits"].shape[1:3])
        for base in ENSEMBLE_BASES:
            scores[f"{base}+att"] = cudam_score(scores[base], attention, sigma)
        scores["cudam"] = scoring.score_batch("cudam", out["logits"], stats=stats, attention_up=attention)
    return scores


def _thin(x: np.ndarray, y: np.ndarray, points: int = 512) -> tuple[list, list]:
    """At most ``points`` evenly spaced points of a curve, both ends kept (for plotting only)."""
    index = np.unique(np.linspace(0, len(x) - 1, min(points, len(x))).round().astype(int))
    return np.asarray(x)[index].tolist(), np.asarray(y)[index].tolist()


def evaluate(net: Network, variables: dict, scale: Scale, log: Callable = print) -> dict:
    """``{"miou", "metrics": {score: {ap, auroc, fpr_at_tpr, ...}}, "curves": {score: {roc, pr}}}``.

    SML statistics from ``scale.stats_frames`` training frames (classes never predicted get the
    pooled statistics); metrics pooled over all anomaly frames; mIoU on ``scale.val_frames``.
    """
    e = net.experiment
    predict = predictor(net.module(), variables)
    batch = e.batch_size if scale.anomaly is None else 1
    train_frames = _batches(frames(e, "train", scale.stats_frames), e.batch_size)
    stats = class_statistics(predict, train_frames)
    mean_std = sml.stats_finalize(stats, missing="pooled")
    val_frames = _batches(frames(e, "val", scale.val_frames), e.batch_size)
    segmentation = segmentation_results(predictions(predict, val_frames), e.num_classes)
    accumulators, kept = {}, {}
    for out in predictions(predict, _batches(anomaly_source(scale, e), batch)):
        labels = np.asarray(out["label"])
        for name, score in _scores(out, mean_std).items():
            accumulators.setdefault(name, AnomalyMetricAccumulator()).update(score, labels)
            kept.setdefault(name, []).append((np.asarray(score).ravel(), labels.ravel()))
    metrics = {name: acc.compute() for name, acc in accumulators.items()}
    curves = {}
    for name, parts in kept.items():
        scores, labels = (np.concatenate(x) for x in zip(*parts))
        fpr, tpr, _ = roc_curve(scores, labels)
        precision, recall, _ = pr_curve(scores, labels)
        curves[name] = {"roc": _thin(fpr, tpr), "pr": _thin(recall, precision)}
    log(f"  evaluated {net.key}: mIoU {100 * segmentation['miou']:.1f}, SML AP {100 * metrics['sml_post']['ap']:.2f}")
    return {"miou": float(segmentation["miou"]), "metrics": metrics, "curves": curves,
            "sml_classes_never_predicted": np.flatnonzero(np.asarray(stats.count) < 2).tolist()}


def evaluation(net: Network, scale: Scale, runs: Path, log: Callable = print) -> dict:
    """``evaluate`` of the trained network, cached in its run folder per evaluation setting."""
    fields = ("stats_frames", "val_frames", "anomaly_frames", "anomaly_split", "anomaly")
    settings = {k: getattr(scale, k) for k in fields}
    tag = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:8]
    cache = runs / net.key / f"evaluation_{tag}.json"
    if cache.exists():
        return json.loads(cache.read_text())
    result = evaluate(net, trained(net, runs, log), scale, log)
    write_json_atomic(cache, result)
    return result


# ---------------------------------------------------------------- tables


def table(rows: Sequence[Row], scale: Scale, runs: Path = RUNS, log: Callable = print) -> tuple[dict, dict]:
    """``(values[label] = {ap, auroc, fpr95, miou, network, score}, curves[label])`` in percent."""
    values, curves = {}, {}
    for row in rows:
        result = evaluation(row.network, scale, runs, log)
        if row.score not in result["metrics"]:
            raise ValueError(f"row {row.label!r}: score {row.score!r} not computed for network {row.network.key} "
                             f"(attention {row.network.experiment.attention}); have {sorted(result['metrics'])}")
        m = result["metrics"][row.score]
        values[row.label] = {"ap": 100 * m["ap"], "auroc": 100 * m["auroc"], "fpr95": 100 * m["fpr_at_tpr"],
                             "miou": 100 * result["miou"], "network": row.network.key, "score": row.score}
        curves[row.label] = result["curves"][row.score]
    return values, curves


def markdown(table: Sequence[dict]) -> str:
    """Table rows ``{label, score, network, miou, ap, fpr95, auroc}`` as markdown (percent, two decimals)."""
    lines = ["| row | score | network | mIoU | AP ↑ | FPR95 ↓ | AUROC ↑ |", "|---|---|---|---|---|---|---|"]
    for v in table:
        lines.append(f"| {v['label']} | `{v['score']}` | `{v['network']}` | {v['miou']:.2f} | {v['ap']:.2f} | "
                     f"{v['fpr95']:.2f} | {v['auroc']:.2f} |")
    return "\n".join(lines)


def run_table(name: str, title: str, rows: Sequence[Row], findings: Callable[[dict], list[Finding]],
              scale: Scale, out_dir: Path = HERE, runs: Path = RUNS, log: Callable = print,
              description: str = "") -> dict:
    """Compute the table, check the findings, write ``<name>.json/.md/_roc.png/_pr.png`` in ``out_dir``."""
    from jaxanom.viz import plot_curves

    log(f"{name}: {title}")
    values, curves = table(rows, scale, runs, log)
    checked = findings(values)
    networks = {row.network.key: row.network.to_dict() for row in rows}
    result = {"name": name, "title": title, "description": description,
              "table": [{"label": k, **v} for k, v in values.items()], "scale": dataclasses.asdict(scale),
              "findings": [dataclasses.asdict(f) for f in checked], "networks": networks,
              "seeds": f"single seed: training, shuffling and synthetic scenes all use seed {scale.seed}"}
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / f"{name}.json", result)
    write_bytes_atomic(out_dir / f"{name}.md", (report(result) + "\n").encode())
    plot_curves(out_dir / f"{name}_roc.png", {k: c["roc"] for k, c in curves.items()}, kind="roc")
    plot_curves(out_dir / f"{name}_pr.png", {k: c["pr"] for k, c in curves.items()}, kind="pr")
    return result


def report(result: dict) -> str:
    """A result as markdown: title, table, findings."""
    lines = [f"## {result['title']}", "", *([result["description"], ""] if result.get("description") else []),
             markdown(result["table"]), "", f"`{result['name']}`; {result['seeds']}.",
             "", "| paper's finding | holds here? | evidence |", "|---|---|---|"]
    lines += [f"| {f['claim']} | {'yes' if f['holds'] else '**no**'} | {f['evidence']} |" for f in result["findings"]]
    return "\n".join(lines)


# ---------------------------------------------------------------- findings

LOWER_IS_BETTER = {"fpr95"}
NAMES = {"ap": "AP", "auroc": "AUROC", "fpr95": "FPR95", "miou": "mIoU"}


def _better(values: dict, a: str, b: str, metric: str) -> bool:
    x, y = values[a][metric], values[b][metric]
    return x < y if metric in LOWER_IS_BETTER else x > y


def improves(values: dict, new: str, old: str, metrics: Sequence[str] = ("ap",), claim: str | None = None) -> Finding:
    """``new`` is better than ``old`` in every metric of ``metrics``."""
    holds = all(_better(values, new, old, m) for m in metrics)
    evidence = ", ".join(f"{NAMES[m]} {values[new][m]:.2f} vs {values[old][m]:.2f}" for m in metrics)
    return Finding(claim or f"{new} beats {old} in {'/'.join(NAMES[m] for m in metrics)}", holds, evidence)


def worse(values: dict, new: str, old: str, metric: str, claim: str) -> Finding:
    """``new`` is worse than ``old`` in ``metric``."""
    return Finding(claim, _better(values, old, new, metric),
                   f"{NAMES[metric]} {values[new][metric]:.2f} vs {values[old][metric]:.2f}")


def not_better(values: dict, new: str, old: str, metric: str, claim: str) -> Finding:
    """``new`` does not improve on ``old`` in ``metric`` (equal or worse)."""
    return Finding(claim, not _better(values, new, old, metric),
                   f"{NAMES[metric]} {values[new][metric]:.2f} vs {values[old][metric]:.2f}")


def ordered(values: dict, labels: Sequence[str], metric: str = "ap", claim: str | None = None) -> Finding:
    """``labels`` strictly increase in quality in this order."""
    holds = all(_better(values, b, a, metric) for a, b in zip(labels, labels[1:]))
    evidence = ", ".join(f"{label} {values[label][metric]:.2f}" for label in labels)
    return Finding(claim or f"{NAMES[metric]}: {' < '.join(labels)}", holds, f"{NAMES[metric]}: {evidence}")


def best(values: dict, winner: str, among: Sequence[str], metric: str = "ap", claim: str | None = None) -> Finding:
    """``winner`` is the best of ``among``."""
    pick = min if metric in LOWER_IS_BETTER else max
    top = pick(among, key=lambda k: values[k][metric])
    evidence = ", ".join(f"{label} {values[label][metric]:.2f}" for label in among)
    return Finding(claim or f"{winner} has the best {NAMES[metric]}", top == winner, f"{NAMES[metric]}: {evidence}")
