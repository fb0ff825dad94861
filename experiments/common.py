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

from jaxanom.app import methods as scoring
from jaxanom import sml
from jaxanom.cudam_score import (PAPER_TEST_POSITIONS, PAPER_TRAIN_POSITIONS, cudam_score, equivalent_weight,
                                 paper_sigma, paper_tau)
from jaxanom.app.evaluate import class_statistics, predictions, predictor, segmentation_results
from jaxanom.app.experiment import Experiment, build_network, frames, jsonable, run_training
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
    """Sizes, data and the segmenter shared by every experiment.

    The defaults are the cheapest competent regime found on 2 CPU cores (``docs/decisions/
    baselines.md``): ``deeplabv3plus_small`` trained 2000 steps on 512 synthetic scenes of 64 x 128
    reaches 60-65% mIoU on the validation frames (the tiny network of earlier runs: 13-18%).
    ``cityscapes_root``: train on Cityscapes (crops of ``height`` x ``width``) instead of synthetic
    scenes. ``anomaly``: ``"road_anomaly:<root>"`` or ``"smiyc:<track root>"`` to score a real
    anomaly dataset instead of the synthetic ``anomaly_split``.
    """

    train_frames: int = 512
    height: int = 64
    width: int = 128
    batch_size: int = 8
    steps: int = 2000
    stats_frames: int = 64
    val_frames: int = 64
    anomaly_frames: int = 64
    anomaly_split: str = "anomaly"
    seed: int = 0
    cityscapes_root: str | None = None
    anomaly: str | None = None
    model: str = "deeplabv3plus_small"

    def __post_init__(self):
        if self.anomaly is not None and self.anomaly.partition(":")[0] not in ANOMALY_READERS:
            raise ValueError(f"anomaly: expected '<reader>:<root>' with reader in {ANOMALY_READERS}, "
                             f"got {self.anomaly!r}")

    @classmethod
    def smoke(cls) -> "Scale":
        """A seconds-long run of the same code (tests)."""
        return cls(train_frames=4, height=64, width=96, batch_size=4, steps=2, stats_frames=2,
                   val_frames=2, anomaly_frames=2, model="deeplabv3plus_tiny")


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
            cudam_position: str = "deep", cudam_gate: str = "paper") -> Network:
    """``scale.model`` (a DeepLabV3+) trained on ``scale``'s data with ``loss``."""
    data = dict(data="cityscapes", data_root=scale.cityscapes_root) if scale.cityscapes_root else {}
    train = TrainConfig(run_dir="", steps=scale.steps, seed=scale.seed, loss=loss, eval_every=scale.steps,
                        save_every=scale.steps, keep=1, progress=False,
                        optim=OptimConfig(name="adamw", lr=2e-3, weight_decay=1e-4,
                                          warmup_steps=max(1, min(30, scale.steps // 10))))
    experiment = Experiment(model=scale.model, attention=attention, train_frames=scale.train_frames,
                            height=scale.height, width=scale.width, crop=(scale.height, scale.width),
                            batch_size=scale.batch_size, cudam_position=cudam_position, cudam_gate=cudam_gate,
                            train=train, **data)
    return Network(experiment)


def plain(scale: Scale) -> Network:
    """No attention, cross-entropy: the baseline of every table."""
    return network(scale)


def cudam(scale: Scale, position: str = "deep", gate: str = "paper", **loss) -> Network:
    """DeepLabV3+ with CuDAM trained with Eq. 8.

    ``loss`` overrides ``LossConfig`` fields; tau defaults to ``matched_tau`` (for ``"output"``,
    whose map covers the whole crop, to the paper-equivalent tau of height * width positions).
    """
    tau = paper_tau(scale.height * scale.width) if position == "output" else matched_tau(scale)
    config = LossConfig(method="cudam", **{"tau": tau, **loss})
    return network(scale, "cudam", config, position, gate)


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
        positions = out.get("attention_positions")
        sigma = matched_sigma(*out["logits"].shape[1:3]) if positions is None else paper_sigma(int(positions))
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
    mean_std = sml.stats_finalize(stats, missing="pooled", policy="none")
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


METRICS = ("ap", "auroc", "fpr95", "miou")


def seed_scales(scale: Scale, seeds: int) -> list[Scale]:
    """``seeds`` copies of ``scale`` with seeds ``scale.seed``, ``scale.seed + 1``, ...: each seeds a
    network's initialisation, its shuffling and its synthetic scenes (training and anomaly frames)."""
    if seeds < 1:
        raise ValueError(f"seeds: expected >= 1, got {seeds}")
    return [dataclasses.replace(scale, seed=scale.seed + i) for i in range(seeds)]


def aggregate(per_seed: Sequence[dict], metrics: Sequence[str] = METRICS) -> dict:
    """Per label: the mean over seeds of every metric of ``metrics``, ``<metric>_std`` (sample std, ddof 1;
    0 for one seed) and ``<metric>_seeds`` (the values); other fields from the first seed, ``networks`` of all."""
    values = {}
    for label, first in per_seed[0].items():
        row = {k: v for k, v in first.items() if k not in metrics}
        row["networks"] = [run[label]["network"] for run in per_seed]
        for metric in metrics:
            xs = np.array([run[label][metric] for run in per_seed], np.float64)
            row[metric] = float(xs.mean())
            row[f"{metric}_std"] = float(xs.std(ddof=1)) if len(xs) > 1 else 0.0
            row[f"{metric}_seeds"] = xs.tolist()
        values[label] = row
    return values


def over_seeds(seed_values: Callable, scale: Scale, seeds: int, runs: Path, log: Callable) -> tuple:
    """``seed_values(scale, runs, log) -> (values, curves, extra)`` for each of ``seed_scales(scale, seeds)``;
    returns ``(scales, aggregate of the values, the first seed's curves, [extra of each seed])``."""
    scales = seed_scales(scale, seeds)
    results = [seed_values(s, runs, log) for s in scales]
    return scales, aggregate([r[0] for r in results]), results[0][1], [r[2] for r in results]


def seeds_text(scales: Sequence[Scale]) -> str:
    """How a result's seeds were used, for its report."""
    seeds = [s.seed for s in scales]
    if len(seeds) == 1:
        return f"single seed: training, shuffling and synthetic scenes all use seed {seeds[0]}"
    return (f"{len(seeds)} seeds ({', '.join(map(str, seeds))}), each seeding a network's initialisation, shuffling "
            "and synthetic scenes; values are mean ± sample std (ddof 1) over seeds, and a finding holds only when "
            "the difference of means exceeds the larger std of the rows it compares")


def _cell(v: dict, metric: str) -> str:
    spread = v.get(f"{metric}_std")
    return f"{v[metric]:.2f}" if not spread else f"{v[metric]:.2f} ± {spread:.2f}"


def markdown(table: Sequence[dict]) -> str:
    """Table rows ``{label, score, network, miou, ap, fpr95, auroc}`` as markdown (percent, two decimals,
    ``± std`` over seeds when there are several)."""
    lines = ["| row | score | network | mIoU | AP ↑ | FPR95 ↓ | AUROC ↑ |", "|---|---|---|---|---|---|---|"]
    for v in table:
        lines.append(f"| {v['label']} | `{v['score']}` | `{v['network']}` | {_cell(v, 'miou')} | {_cell(v, 'ap')} | "
                     f"{_cell(v, 'fpr95')} | {_cell(v, 'auroc')} |")
    return "\n".join(lines)


def run_table(name: str, title: str, rows, findings: Callable[[dict], list[Finding]],
              scale: Scale, out_dir: Path = HERE, runs: Path = RUNS, log: Callable = print,
              description: str = "", seeds: int = 1) -> dict:
    """Compute the table over ``seeds`` seeds, check the findings on the means (against the spread),
    write ``<name>.json/.md/_roc.png/_pr.png`` in ``out_dir`` (curves: the first seed's).

    ``rows``: a list of ``Row`` (one seed only) or a function ``rows(scale)`` giving them for a seed.
    """
    log(f"{name}: {title}")
    scales = seed_scales(scale, seeds)
    if not callable(rows) and seeds != 1:
        raise ValueError("rows: pass a function rows(scale) to run several seeds")
    per_seed, curves, networks = [], None, {}
    for s in scales:
        seed_rows = rows(s) if callable(rows) else rows
        values, seed_curves = table(seed_rows, s, runs, log)
        per_seed.append(values)
        curves = curves or seed_curves
        networks.update({row.network.key: row.network.to_dict() for row in seed_rows})
    return write_table(name, title, aggregate(per_seed), curves, findings, scales, networks, out_dir, description)


def write_table(name: str, title: str, values: dict, curves: dict, findings: Callable[[dict], list[Finding]],
                scales: Sequence[Scale], networks: dict, out_dir: Path, description: str = "",
                steps_text: str = "") -> dict:
    """Check the findings on ``values`` (from ``aggregate``) and write the result files; returns the result.
    ``steps_text`` replaces "<steps> training steps per network" where networks train for different steps."""
    from jaxanom.viz import plot_curves

    checked = findings(values)
    result = {"name": name, "title": title, "description": description,
              "table": [{"label": k, **v} for k, v in values.items()], "scale": dataclasses.asdict(scales[0]),
              "findings": [dataclasses.asdict(f) for f in checked], "networks": networks,
              "seeds": seeds_text(scales), "num_seeds": len(scales), **({"steps_text": steps_text} if steps_text else {})}
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / f"{name}.json", result)
    write_bytes_atomic(out_dir / f"{name}.md", (report(result) + "\n").encode())
    plot_curves(out_dir / f"{name}_roc.png", {k: c["roc"] for k, c in curves.items()}, kind="roc")
    plot_curves(out_dir / f"{name}_pr.png", {k: c["pr"] for k, c in curves.items()}, kind="pr")
    return result


def report(result: dict) -> str:
    """A result as markdown: title, table, findings."""
    steps = result.get("steps_text") or f"{result['scale']['steps']} training steps per network"
    lines = [f"## {result['title']}", "", *([result["description"], ""] if result.get("description") else []),
             markdown(result["table"]), "",
             f"`{result['name']}`; {steps}; {result['seeds']}.",
             "", "| paper's finding | holds here? | evidence |", "|---|---|---|"]
    lines += [f"| {f['claim']} | {'yes' if f['holds'] else '**no**'} | {f['evidence']} |" for f in result["findings"]]
    return "\n".join(lines)


# ---------------------------------------------------------------- findings

LOWER_IS_BETTER = {"fpr95"}
NAMES = {"ap": "AP", "auroc": "AUROC", "fpr95": "FPR95", "miou": "mIoU"}


def _better(values: dict, a: str, b: str, metric: str) -> bool:
    """``a`` beats ``b`` by more than the spread over seeds (the larger std of the two; 0 for one seed)."""
    x, y = values[a][metric], values[b][metric]
    spread = max(values[a].get(f"{metric}_std", 0.0), values[b].get(f"{metric}_std", 0.0))
    margin = y - x if metric in LOWER_IS_BETTER else x - y
    return margin > spread


def _pair(values: dict, a: str, b: str, metric: str) -> str:
    return f"{NAMES[metric]} {_cell(values[a], metric)} vs {_cell(values[b], metric)}"


def improves(values: dict, new: str, old: str, metrics: Sequence[str] = ("ap",), claim: str | None = None) -> Finding:
    """``new`` is better than ``old`` in every metric of ``metrics``."""
    holds = all(_better(values, new, old, m) for m in metrics)
    evidence = ", ".join(_pair(values, new, old, m) for m in metrics)
    return Finding(claim or f"{new} beats {old} in {'/'.join(NAMES[m] for m in metrics)}", holds, evidence)


def worse(values: dict, new: str, old: str, metric: str, claim: str) -> Finding:
    """``new`` is worse than ``old`` in ``metric``."""
    return Finding(claim, _better(values, old, new, metric), _pair(values, new, old, metric))


def not_better(values: dict, new: str, old: str, metric: str, claim: str) -> Finding:
    """``new`` does not improve on ``old`` in ``metric`` (equal or worse)."""
    return Finding(claim, not _better(values, new, old, metric), _pair(values, new, old, metric))


def ordered(values: dict, labels: Sequence[str], metric: str = "ap", claim: str | None = None) -> Finding:
    """``labels`` strictly increase in quality in this order."""
    holds = all(_better(values, b, a, metric) for a, b in zip(labels, labels[1:]))
    evidence = ", ".join(f"{label} {_cell(values[label], metric)}" for label in labels)
    return Finding(claim or f"{NAMES[metric]}: {' < '.join(labels)}", holds, f"{NAMES[metric]}: {evidence}")


def best(values: dict, winner: str, among: Sequence[str], metric: str = "ap", claim: str | None = None) -> Finding:
    """``winner`` is the best of ``among``."""
    holds = all(_better(values, winner, other, metric) for other in among if other != winner)
    evidence = ", ".join(f"{label} {_cell(values[label], metric)}" for label in among)
    return Finding(claim or f"{winner} has the best {NAMES[metric]} (by more than the spread)", holds,
                   f"{NAMES[metric]}: {evidence}")
