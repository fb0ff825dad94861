"""What every paper-table experiment shares: networks, cached training, evaluation, tables, findings.

An experiment file lists the rows of its table, each a ``Row(label, network, score)``, and the
paper's qualitative findings as functions of the table. ``run_table`` trains every network once
into ``runs/<hash of its configuration>/`` (so experiments with an identical configuration share
it, and an interrupted run resumes), fits the SML class statistics on training frames, scores the
anomaly frames with every score, and writes ``<name>.json``, ``<name>.md``, ``<name>_roc.png`` and
``<name>_pr.png`` beside the experiment file.

Findings are paired comparisons: every row keeps per-frame histograms of its score and per-frame
confusion matrices (cached beside the evaluation), one hierarchical bootstrap over seeds and frames
(``paired_replicates``) serves every row, and a finding holds when the 95% interval of the paired
difference lies on the paper's side of 0 (``comparison``). A finding is *tested* only where every
network of its rows reaches ``COMPETENT_MIOU``. An experiment file may also define ``controls(values)
-> [Finding]``: positive controls, rows built so that the mechanism must help (``scaled_logits``);
a failing control points at a bug.

Networks are trained with AdamW (lr 2e-3, as ``jaxanom demo``) instead of the papers' SGD (lr 0.01
for tens of thousands of steps), because the budget here is a few hundred steps.

CuDAM's constants are per-pixel magnitudes for attention maps of the paper's size: tau = 5e4 for
a 180 x 180 training map (720 x 720 crops, §IV-D) and sigma = 2e4 for 256 x 512 test maps
(1024 x 2048 frames at stride 4). A map sums to 1, so its values scale as 1 / (h * w); the
defaults here scale tau and sigma by the ratio of map sizes (``matched_tau``, ``matched_sigma``,
through ``jaxanom.cudam.score.equivalent_weight``)
so that ``tau * M_att`` has the paper's magnitude. The paper's literal values are rows of their own
(``cudam_fig6`` trains with tau = 5e4; the score ``cudam`` uses sigma = 2e4).
"""
from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from experiments.jobs import Job
from experiments.stats import (REPLICATES, bin_edges, binned_auroc, binned_metrics, frame_histograms, hierarchical,
                               hierarchical_draws, interval)
from jaxanom import sml
from jaxanom.cudam.score import (PAPER_TEST_POSITIONS, PAPER_TRAIN_POSITIONS, cudam_score, equivalent_weight,
                                 paper_sigma, paper_tau)
from jaxanom.app.evaluate import class_statistics, predictions, predictor
from jaxanom.app.scoring import inputs_of, score_all
from jaxanom.app.experiment import Experiment, build_network, frames, jsonable, run_training
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.metrics import confusion_scores, miou, pr_curve, roc_curve
from jaxanom.metrics.evaluator import PixelAnomaly, Segmentation, update_keyed
from jaxanom.train.segmenter import TrainConfig
from jaxanom.train.optim import OptimConfig
from jaxanom.cudam.objective import CuDAM
from jaxanom.losses import CrossEntropy
from jaxanom.msaam.objective import MSAAM
from jaxanom.objectives import Objective

HERE = Path(__file__).parent
RUNS = HERE / "runs"
PAPER_TAU, PAPER_SIGMA = 5e4, 2e4
ANOMALY_READERS = ("road_anomaly", "smiyc")
# Scores every network gets; "<base>+att" is the CuDAM ensemble (Eq. 10) of <base> with the
# network's attention at the matched sigma, "cudam" the library's (SML + 2e4 * attention).
BASE_SCORES = ("msp", "max_logit", "entropy", "sml", "sml_suppress", "sml_smooth", "sml_post",
               "msp_post", "max_logit_post")
ENSEMBLE_BASES = ("msp", "max_logit", "sml_post")
# Per-frame histograms of every score over this many bins (``experiments.stats``) give the intervals.
TABLE_BINS = 2048
# A finding is tested only where every segmenter of the rows it compares reaches this mIoU (percent).
COMPETENT_MIOU = 60.0


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
        """The smallest run of the same code (``--smoke``, tests): tiny networks trained for 2 steps."""
        return cls(train_frames=4, height=64, width=96, batch_size=4, steps=2, stats_frames=2,
                   val_frames=2, anomaly_frames=2, model="deeplabv3plus_tiny")


def _hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:12]


@dataclasses.dataclass(frozen=True)
class Network:
    """A trainable ``Experiment``, named by the hash of its configuration.

    ``class_scale``: per-class factors (C,); every logit of a pixel is multiplied by the factor of the
    pixel's predicted class before any score or SML statistics (a positive control, ``scaled_logits``;
    predictions and mIoU unchanged); the weights stay those of the unscaled network (``run_key``),
    only the evaluation differs (``key``).
    """

    experiment: Experiment
    class_scale: tuple[float, ...] | None = None

    def to_dict(self) -> dict:
        config = jsonable(self.experiment)
        return config if self.class_scale is None else {**config, "class_scale": list(self.class_scale)}

    @property
    def key(self) -> str:
        """Hash of the configuration (with ``class_scale``): the network's name in tables."""
        return _hash(self.to_dict())

    @property
    def run_key(self) -> str:
        """Hash of the trained configuration: the run folder's name."""
        return _hash(jsonable(self.experiment))

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
    """A qualitative claim of the paper (or a positive control) and whether this run reproduces it.

    ``rows``: the table rows it compares; ``intervals``: its ``comparison`` of each pair of rows;
    ``tested`` / ``untested_because``: ``competence`` of the rows' networks (None: not checked).
    """

    claim: str
    holds: bool
    evidence: str
    rows: list[str] = dataclasses.field(default_factory=list)
    intervals: list[dict] = dataclasses.field(default_factory=list)
    tested: bool | None = None
    untested_because: str = ""


def attention_positions(height: int, width: int) -> int:
    """Positions of CuDAM's map for an ``height`` x ``width`` input (stride 4: ceil(ceil(H/2)/2))."""
    return math.ceil(math.ceil(height / 2) / 2) * math.ceil(math.ceil(width / 2) / 2)


def matched_tau(scale: Scale) -> float:
    """The reward weight whose ``tau * M_att`` matches the paper's tau = 5e4 on 180 x 180 maps."""
    return equivalent_weight(PAPER_TAU, attention_positions(scale.height, scale.width), PAPER_TRAIN_POSITIONS)


def matched_sigma(height: int, width: int) -> float:
    """The ensemble weight matching the paper's sigma = 2e4 on 256 x 512 maps, for ``height`` x ``width`` frames."""
    return equivalent_weight(PAPER_SIGMA, attention_positions(height, width), PAPER_TEST_POSITIONS)


def warmup_steps(steps: int) -> int:
    """The linear warm-up of a network trained ``steps`` steps (a tenth, 1 to 30); the schedule
    needs at least one step after it, so ``steps`` >= 2."""
    return max(1, min(30, steps // 10))


def network(scale: Scale, attention: str | None = None, objective: Objective = CrossEntropy(),
            cudam_position: str = "deep", cudam_gate: str = "paper") -> Network:
    """``scale.model`` (a DeepLabV3+) trained on ``scale``'s data with ``objective``."""
    data = dict(data="cityscapes", data_root=scale.cityscapes_root) if scale.cityscapes_root else {}
    train = TrainConfig(run_dir="", steps=scale.steps, seed=scale.seed, objective=objective, eval_every=scale.steps,
                        save_every=scale.steps, keep=1, progress=False,
                        optim=OptimConfig(name="adamw", lr=2e-3, weight_decay=1e-4,
                                          warmup_steps=warmup_steps(scale.steps)))
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

    ``loss`` overrides ``CuDAM`` objective fields; tau defaults to ``matched_tau`` (for ``"output"``,
    whose map covers the whole crop, to the paper-equivalent tau of height * width positions).
    """
    tau = paper_tau(scale.height * scale.width) if position == "output" else matched_tau(scale)
    return network(scale, "cudam", CuDAM(**{"tau": tau, **loss}), position, gate)


def msaam(scale: Scale) -> Network:
    """DeepLabV3+ with MSAAM trained with its loss (Eq. 7)."""
    return network(scale, "msaam", MSAAM())


def control_scales(num_classes: int) -> tuple[float, ...]:
    """Deliberately different per-class logit factors: a geometric spread from 1/4 to 4 in class order."""
    return tuple(np.geomspace(0.25, 4.0, num_classes).tolist())


def scaled_logits(net: Network) -> Network:
    """``net`` with each pixel's logits multiplied by its predicted class's factor of ``control_scales`` (no
    retraining): the classes' logit scales differ by up to 16x, so max logit ranks pixels by their class's
    factor, while SML (Eq. 5, fitted on the scaled logits) divides it out exactly: (s L - s mu) / (s sigma)."""
    return dataclasses.replace(net, class_scale=control_scales(net.experiment.num_classes))


def _scaled(predict: Callable, factors: Sequence[float]) -> Callable:
    """``predict`` with every pixel's logits (..., C) multiplied by ``factors[predicted class]``."""
    factors = np.asarray(factors, np.float32)

    def scaled(images):
        out = predict(images)
        logits = np.asarray(out["logits"])
        return {**out, "logits": logits * factors[np.argmax(logits, -1)][..., None]}

    return scaled


def oracle_attention(labels: np.ndarray, positions: int) -> np.ndarray:
    """(B, H, W) float32: the upsampled map of an attention of ``positions`` cells that spends all its mass,
    evenly, on the anomaly pixels (1) of ``labels`` (B, H, W): 1 / (anomalous share * positions) there,
    0 elsewhere; a frame without anomaly gets the uniform 1 / positions. Values keep a real map's
    magnitude, so Eq. 10 with it at the matched sigma must beat its base score (CuDAM's positive control;
    a mis-scaled sigma, upsampling or ensemble fails it)."""
    anomaly = (np.asarray(labels) == 1).astype(np.float32)
    share = anomaly.mean(axis=(1, 2), keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(share > 0, anomaly / (share * positions), np.float32(1 / positions)).astype(np.float32)


LOGIT_SCALE_CONTROL = "control: logits scaled by predicted class, 1/4..4, "
ORACLE_CONTROL = "control: SML + attention on the anomalies only (Eq. 10, matched sigma)"
ORACLE_BASE = "control: SML of the same network, no attention term"


def logit_scale_rows(net: Network) -> list[Row]:
    """The rows of SML's positive control on ``net``: max logit and SML of ``scaled_logits(net)``."""
    return [Row(LOGIT_SCALE_CONTROL + "max logit", scaled_logits(net), "max_logit"),
            Row(LOGIT_SCALE_CONTROL + "SML", scaled_logits(net), "sml")]


def logit_scale_control(values: dict) -> Finding:
    """SML must beat max logit in AP when the classes' logit scales differ (``logit_scale_rows``)."""
    return improves(values, LOGIT_SCALE_CONTROL + "SML", LOGIT_SCALE_CONTROL + "max logit", ("ap",),
                    "SML beats max logit when the classes' logit scales differ (1/4 to 4)")


def oracle_rows(net: Network) -> list[Row]:
    """The rows of CuDAM's positive control on ``net`` (a network with attention): Eq. 10 with
    ``oracle_attention`` and its base score, SML with post-processing."""
    return [Row(ORACLE_CONTROL, net, "sml_post+oracle"), Row(ORACLE_BASE, net, "sml_post")]


def oracle_control(values: dict) -> Finding:
    """Eq. 10 with an attention map on the anomalies must beat its base score in AP and AUROC (``oracle_rows``)."""
    return improves(values, ORACLE_CONTROL, ORACLE_BASE, ("ap", "auroc"),
                    "Eq. 10 at the matched sigma, with an attention map that covers the anomalies, beats SML alone")


# ---------------------------------------------------------------- training


_RESTORED: dict[Path, dict] = {}  # final checkpoint -> variables, kept for this process's other evaluations


def trained(net: Network, runs: Path, log: Callable = print) -> dict:
    """The network's final variables: trained into ``runs/<run_key>/``, or restored when already there
    (once per process: a network evaluated twice, e.g. with ``scaled_logits``, is restored once).

    No validation during training: ``evaluate`` measures mIoU afterwards.
    """
    e = net.experiment
    run_dir = runs / net.run_key
    final = (run_dir / "checkpoints" / str(e.train.steps)).resolve()
    if final in _RESTORED and final.exists():
        return _RESTORED[final]
    done = final.exists()
    log(f"  network {net.run_key}: {'restoring' if done else 'training'} {e.attention or 'plain'} "
        f"({e.train.objective.name} objective, {e.train.steps} steps)")
    start = time.perf_counter()
    variables = run_training(e, run_dir, progress=False, validate=False)
    if not done:
        log(f"  trained in {time.perf_counter() - start:.0f} s")
    _RESTORED[final] = variables
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
    """Every score of one batch of outputs (see ``BASE_SCORES``, ``ENSEMBLE_BASES``); with attention also
    ``"sml_post+oracle"``, Eq. 10 with ``oracle_attention`` in place of the network's map (a control)."""
    attention = out.get("attention_up")
    names = (*BASE_SCORES, "cudam") if attention is not None else BASE_SCORES
    options = {"cudam": {"cudam_sigma": PAPER_SIGMA}} if "cudam" in names else {}  # the paper's literal sigma
    scores, _ = score_all(names, inputs_of(out, stats), options)
    if attention is not None:
        positions = out.get("attention_positions")
        positions = attention_positions(*out["logits"].shape[1:3]) if positions is None else int(positions)
        sigma = paper_sigma(positions)
        for base in ENSEMBLE_BASES:
            scores[f"{base}+att"] = cudam_score(scores[base], attention, sigma)
        scores["sml_post+oracle"] = cudam_score(scores["sml_post"], oracle_attention(out["label"], positions), sigma)
        scores["cudam"] = scores.pop("cudam")  # last, as the cached evaluations hold it
    return scores


def _thin(x: np.ndarray, y: np.ndarray, points: int = 512) -> tuple[list, list]:
    """At most ``points`` evenly spaced points of a curve, both ends kept (for plotting only)."""
    index = np.unique(np.linspace(0, len(x) - 1, min(points, len(x))).round().astype(int))
    return np.asarray(x)[index].tolist(), np.asarray(y)[index].tolist()


def _anomaly_metrics(histograms: np.ndarray) -> dict[str, np.ndarray]:
    """Percent AP, FPR95 and AUROC of pooled histograms (..., bins, 2) (``experiments.stats``)."""
    binned = binned_metrics(histograms)
    return {"ap": 100 * binned["ap"], "fpr95": 100 * binned["fpr_at_tpr"], "auroc": 100 * binned_auroc(histograms)}


def _miou(confusions: np.ndarray) -> dict[str, np.ndarray]:
    """Percent mIoU of each pooled confusion matrix (n, C, C)."""
    return {"miou": 100 * confusion_scores(confusions)["miou"]}


def frame_confusions(outputs, num_classes: int) -> np.ndarray:
    """(V, C, C) int64 confusion matrices (rows: label) of every frame of batches ``{"logits", "label"}``."""
    return np.concatenate([Segmentation(num_classes).frame_states(out) for out in outputs])


def score_histograms(scores: list[np.ndarray], labels: list[np.ndarray]) -> tuple[np.ndarray, dict]:
    """Per-frame histograms (F, TABLE_BINS + 1, 2) int32 of one score's frames over bins at the quantiles of
    its pooled values, and the percent metrics of all frames' histograms (the binning's check)."""
    histograms = frame_histograms(scores, labels, bin_edges(scores, labels, TABLE_BINS))
    with np.errstate(invalid="ignore", divide="ignore"):
        binned = {k: float(v) for k, v in _anomaly_metrics(histograms.sum(0)).items()}
    return histograms.astype(np.int32), binned


def evaluate(net: Network, variables: dict, scale: Scale, log: Callable = print) -> tuple[dict, dict]:
    """``(result, frames)``: ``result = {"miou", "metrics": {score: {ap, auroc, fpr_at_tpr, ...}},
    "curves": {score: {roc, pr}}, "binned": {score: {ap, fpr95, auroc}}}`` and ``frames =
    {"confusion": (V, C, C) int64, "histograms_<score>": (F, TABLE_BINS + 1, 2) int32}``.

    SML statistics from ``scale.stats_frames`` training frames (classes never predicted get the
    pooled statistics); metrics pooled over all anomaly frames; mIoU on ``scale.val_frames``.
    ``frames`` keeps what the bootstrap resamples: per validation frame its confusion matrix, per
    anomaly frame and score its histogram over ``TABLE_BINS`` bins at the quantiles of the pooled
    score; ``binned`` (percent) is the metric of all frames' histograms, the binning's check.
    """
    e = net.experiment
    predict = predictor(net.module(), variables)
    if net.class_scale is not None:
        predict = _scaled(predict, net.class_scale)
    batch = e.batch_size if scale.anomaly is None else 1
    train_frames = _batches(frames(e, "train", scale.stats_frames), e.batch_size)
    stats = class_statistics(predict, train_frames)
    mean_std = sml.stats_finalize(stats, missing="pooled", policy="none")
    val_frames = _batches(frames(e, "val", scale.val_frames), e.batch_size)
    confusions = frame_confusions(predictions(predict, val_frames), e.num_classes)
    pixels, kept, labels = {}, {}, []
    for out in predictions(predict, _batches(anomaly_source(scale, e), batch)):
        label = np.asarray(out["label"])
        labels.extend(label)
        scores = _scores(out, mean_std)
        for name, score in scores.items():
            update_keyed(pixels, name, lambda: PixelAnomaly(name), {"scores": scores, "label": label})
            kept.setdefault(name, []).extend(np.asarray(score, np.float32))
    metrics = {name: evaluator.finalize(state) for name, (evaluator, state) in pixels.items()}
    curves, binned, arrays = {}, {}, {"confusion": confusions}
    for name, per_frame in kept.items():
        scores, pooled_labels = np.concatenate([x.ravel() for x in per_frame]), np.concatenate([x.ravel() for x in labels])
        fpr, tpr, _ = roc_curve(scores, pooled_labels)
        precision, recall, _ = pr_curve(scores, pooled_labels)
        curves[name] = {"roc": _thin(fpr, tpr), "pr": _thin(recall, precision)}
        arrays[f"histograms_{name}"], binned[name] = score_histograms(per_frame, labels)
    segmentation = miou(confusions.sum(0))
    log(f"  evaluated {net.key}: mIoU {100 * segmentation:.1f}, SML AP {100 * metrics['sml_post']['ap']:.2f}")
    result = {"miou": float(segmentation), "metrics": metrics, "curves": curves, "binned": binned,
              "sml_classes_never_predicted": np.flatnonzero(np.asarray(stats.count) < 2).tolist()}
    return result, arrays


def evaluation_cache(net: Network, scale: Scale, runs: Path) -> Path:
    """``runs/<run_key>/evaluation_<tag>.json``: ``evaluation``'s cache for the settings of ``scale`` it reads."""
    fields = ("stats_frames", "val_frames", "anomaly_frames", "anomaly_split", "anomaly")
    settings = {k: getattr(scale, k) for k in fields}
    if net.class_scale is not None:
        settings["class_scale"] = list(net.class_scale)
    tag = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:8]
    return runs / net.run_key / f"evaluation_{tag}.json"


def evaluate_networks(nets: Sequence[Network], scale: Scale, runs: Path) -> None:
    """``evaluation`` of networks that share one run folder, one after the other (a ``jobs.Job``)."""
    for net in nets:
        evaluation(net, scale, runs)


def table_jobs(rows, scale: Scale, seeds: int, runs: Path) -> list[Job]:
    """One job per run folder that ``run_table(rows=rows)`` over ``seeds`` would train or evaluate and has
    not cached yet: ``evaluate_networks`` of its rows' networks."""
    folders: dict[str, tuple[Scale, dict]] = {}
    for s in seed_scales(scale, seeds):
        for row in rows(s) if callable(rows) else rows:
            folders.setdefault(row.network.run_key, (s, {}))[1][row.network.key] = row.network
    return [Job(f"network {key}", evaluate_networks, (list(nets.values()), s, runs), s.steps / 700)
            for key, (s, nets) in folders.items()
            if not all(evaluation_cache(n, s, runs).with_suffix(".npz").exists() for n in nets.values())]


def evaluation(net: Network, scale: Scale, runs: Path, log: Callable = print) -> tuple[dict, dict]:
    """``evaluate`` of the trained network, cached in its run folder per evaluation setting:
    ``evaluation_<tag>.json`` and the per-frame arrays in ``evaluation_<tag>.npz`` (the JSON names the
    arrays' hash; a cache without them, or with other arrays, is recomputed)."""
    cache = evaluation_cache(net, scale, runs)
    arrays_file = cache.with_suffix(".npz")
    if cache.exists() and arrays_file.exists():
        result, data = json.loads(cache.read_text()), arrays_file.read_bytes()
        if result.get("frames") == hashlib.sha256(data).hexdigest():
            with np.load(io.BytesIO(data)) as arrays:
                return result, {k: arrays[k] for k in arrays.files}
    result, arrays = evaluate(net, trained(net, runs, log), scale, log)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    write_bytes_atomic(arrays_file, buffer.getvalue())
    result["frames"] = hashlib.sha256(buffer.getvalue()).hexdigest()
    write_json_atomic(cache, result)
    return result, arrays


# ---------------------------------------------------------------- tables


def table(rows: Sequence[Row], scale: Scale, runs: Path = RUNS, log: Callable = print) -> tuple[dict, dict, dict]:
    """``(values[label] = {ap, auroc, fpr95, miou, network, score, binning}, curves[label], frames[label])`` in
    percent; ``frames[label] = {"histograms": (F, bins, 2), "confusion": (V, C, C)}`` (``evaluate``)
    and ``binning``: the largest |binned - exact| of AP, FPR95 and AUROC (points)."""
    values, curves, kept = {}, {}, {}
    for row in rows:
        result, arrays = evaluation(row.network, scale, runs, log)
        if row.score not in result["metrics"]:
            raise ValueError(f"row {row.label!r}: score {row.score!r} not computed for network {row.network.key} "
                             f"(attention {row.network.experiment.attention}); have {sorted(result['metrics'])}")
        m = result["metrics"][row.score]
        exact = {"ap": 100 * m["ap"], "auroc": 100 * m["auroc"], "fpr95": 100 * m["fpr_at_tpr"]}
        gap = max(abs(result["binned"][row.score][k] - v) for k, v in exact.items())
        values[row.label] = {**exact, "miou": 100 * result["miou"], "network": row.network.key, "score": row.score,
                             "binning": gap}
        curves[row.label] = result["curves"][row.score]
        kept[row.label] = {"histograms": arrays[f"histograms_{row.score}"], "confusion": arrays["confusion"]}
    return values, curves, kept


def paired_replicates(per_seed: Sequence[dict], replicates: int = REPLICATES, seed: int = 0) -> dict:
    """Bootstrap replicates (percent) of every row's AP, FPR95, AUROC and mIoU: ``{label: {metric: (R,)}}``.

    ``per_seed[s][label]``: the ``frames`` of ``table`` for seed s. One set of ``stats.hierarchical_draws``
    (seeds, then each seed's anomaly and validation frames, with replacement) serves every row, so the
    rows' replicates are paired; a replicate is the mean over its drawn seeds of the metric of the drawn
    frames (with one seed, the bootstrap over frames). Deterministic in ``seed``.
    """
    counts = {}
    for kind, key in (("anomaly", "histograms"), ("val", "confusion")):
        per_row = {label: [len(frames[label][key]) for frames in per_seed] for label in per_seed[0]}
        if len({tuple(c) for c in per_row.values()}) != 1:
            raise ValueError(f"per_seed: rows compared on different {kind} frames: {per_row}")
        counts[kind] = next(iter(per_row.values()))
    draws = hierarchical_draws(counts, replicates, seed)
    return {label: {**hierarchical([f[label]["histograms"] for f in per_seed], draws, "anomaly", _anomaly_metrics),
                    **hierarchical([f[label]["confusion"] for f in per_seed], draws, "val", _miou)}
            for label in per_seed[0]}


METRICS = ("ap", "auroc", "fpr95", "miou")


def seed_scales(scale: Scale, seeds: int) -> list[Scale]:
    """``seeds`` copies of ``scale`` with seeds ``scale.seed``, ``scale.seed + 1``, ...: each seeds a
    network's initialisation, its shuffling and its synthetic scenes (training and anomaly frames)."""
    if seeds < 1:
        raise ValueError(f"seeds: expected >= 1, got {seeds}")
    return [dataclasses.replace(scale, seed=scale.seed + i) for i in range(seeds)]


def aggregate(per_seed: Sequence[dict], metrics: Sequence[str] = METRICS) -> dict:
    """Per label: the mean over seeds of every metric of ``metrics``, ``<metric>_std`` (sample std, ddof 1;
    0 for one seed) and ``<metric>_seeds`` (the values); other fields from the first seed, ``networks`` of all
    (``binning``: the largest over seeds)."""
    values = {}
    for label, first in per_seed[0].items():
        row = {k: v for k, v in first.items() if k not in metrics}
        row["networks"] = [run[label]["network"] for run in per_seed]
        if "binning" in first:
            row["binning"] = max(run[label]["binning"] for run in per_seed)
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


def seeds_text(scales: Sequence[Scale], paired: bool = True) -> str:
    """How a result's seeds were used and how its findings are decided, for its report. ``paired``: the
    rows carry bootstrap replicates (``paired_replicates``); else the older rule (``_better``)."""
    seeds = [s.seed for s in scales]
    if len(seeds) == 1:
        text = f"single seed: training, shuffling and synthetic scenes all use seed {seeds[0]}"
    else:
        text = (f"{len(seeds)} seeds ({', '.join(map(str, seeds))}), each seeding a network's initialisation, "
                "shuffling and synthetic scenes; values are mean ± sample std (ddof 1) over seeds")
    if not paired:
        return text + ("; no paired intervals: a finding holds when the difference of means exceeds the larger std "
                       "of the rows it compares" if len(seeds) > 1 else "; no paired intervals: a finding holds on "
                       "the sign of the difference alone")
    level = "seeds and, inside each, frames" if len(seeds) > 1 else "frames"
    return (text + f"; a finding holds when the 95% interval of the paired difference (a bootstrap of {REPLICATES} "
            f"replicates resampling {level} with replacement, the same draws for every row) excludes 0 in the "
            "paper's direction")


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
              description: str = "", seeds: int = 1,
              controls: Callable[[dict], list[Finding]] | None = None) -> dict:
    """Compute the table over ``seeds`` seeds, attach every row's paired bootstrap replicates
    (``paired_replicates``), check the findings and the positive ``controls`` (both ``f(values) ->
    [Finding]``), write ``<name>.json/.md/_roc.png/_pr.png`` in ``out_dir`` (curves: the first seed's).

    ``rows``: a list of ``Row`` (one seed only) or a function ``rows(scale)`` giving them for a seed.
    """
    log(f"{name}: {title}")
    scales = seed_scales(scale, seeds)
    if not callable(rows) and seeds != 1:
        raise ValueError("rows: pass a function rows(scale) to run several seeds")
    per_seed, per_seed_frames, curves, networks, run_keys = [], [], None, {}, set()
    for s in scales:
        seed_rows = rows(s) if callable(rows) else rows
        values, seed_curves, seed_frames = table(seed_rows, s, runs, log)
        per_seed.append(values)
        per_seed_frames.append(seed_frames)
        curves = curves or seed_curves
        networks.update({row.network.key: row.network.to_dict() for row in seed_rows})
        run_keys.update(row.network.run_key for row in seed_rows)
    values = aggregate(per_seed)
    for label, replicates in paired_replicates(per_seed_frames).items():
        values[label]["replicates"] = replicates
    minutes = training_minutes(runs, run_keys)
    if minutes is not None:
        description = (f"{description} Run time: {minutes:.1f} min to train the table's networks ({len(run_keys)} "
                       "runs, from their logs, each under the load of the run that trained it); evaluating them takes "
                       "seconds to minutes more.").strip()
    return write_table(name, title, values, curves, findings, scales, networks, out_dir, description,
                       controls=controls)


def training_minutes(runs: Path, run_keys) -> float | None:
    """Wall minutes that training the networks of ``run_keys`` took, from their ``runs/<key>/log.jsonl``: the
    times between consecutive logged steps where the step grows (a restart's gap, where the step falls back,
    is left out), summed over the runs; None when a run has no logged step."""
    total = 0.0
    for key in set(run_keys):
        log = runs / key / "log.jsonl"
        records = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
        if not records:
            return None
        total += sum(b["time"] - a["time"] for a, b in zip(records, records[1:]) if b["step"] > a["step"])
    return total / 60


def competence(values: dict, rows: Sequence[str]) -> tuple[bool | None, str]:
    """``(tested, why not)``: whether every network of ``rows`` reaches its competence bar (the row's
    ``competent_miou``, where its regime sets one, else ``COMPETENT_MIOU``); None when the rows carry no
    mIoU (or no rows are named)."""
    mious = {label: values[label]["miou"] for label in rows if "miou" in values.get(label, {})}
    if not rows or len(mious) != len(rows):
        return None, "no segmenter mIoU to check"
    low = {}  # network -> (first row of it, mIoU, its bar)
    for label, m in mious.items():
        bar = values[label].get("competent_miou", COMPETENT_MIOU)
        if m < bar:
            low.setdefault(values[label].get("network", label), (label, m, bar))
    if not low:
        return True, ""
    bar = next(iter(low.values()))[2]  # one regime's rows share a bar
    return False, f"mIoU below {bar:.0f}%: " + ", ".join(f"{label} (`{k}`) {m:.1f}" for k, (label, m, _) in low.items())


def _row_json(label: str, v: dict) -> dict:
    """A table row for the JSON: replicates replaced by each metric's 95% interval."""
    row = {"label": label, **{k: x for k, x in v.items() if k != "replicates"}}
    for metric, replicates in v.get("replicates", {}).items():
        row[f"{metric}_interval"] = list(interval(replicates))
    return row


def write_table(name: str, title: str, values: dict, curves: dict, findings: Callable[[dict], list[Finding]],
                scales: Sequence[Scale], networks: dict, out_dir: Path, description: str = "",
                steps_text: str = "", controls: Callable[[dict], list[Finding]] | None = None) -> dict:
    """Check the findings and positive ``controls`` on ``values`` (from ``aggregate``, rows with
    ``"replicates"`` where paired intervals exist) and write the result files; returns the result.
    ``steps_text`` replaces "<steps> training steps per network" where networks train for different steps."""
    from jaxanom.viz import plot_curves

    paired = all("replicates" in v for v in values.values())
    binning = [v["binning"] for v in values.values() if "binning" in v]
    result = {"name": name, "title": title, "description": description,
              "table": [_row_json(k, v) for k, v in values.items()], "scale": dataclasses.asdict(scales[0]),
              "findings": [dataclasses.asdict(f) for f in findings(values)],
              "controls": [dataclasses.asdict(f) for f in (controls(values) if controls else [])],
              "networks": networks, "seeds": seeds_text(scales, paired), "num_seeds": len(scales), "paired": paired,
              **({"binning": max(binning)} if binning else {}), **({"steps_text": steps_text} if steps_text else {})}
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / f"{name}.json", result)
    write_bytes_atomic(out_dir / f"{name}.md", (report(result) + "\n").encode())
    plot_curves(out_dir / f"{name}_roc.png", {k: c["roc"] for k, c in curves.items()}, kind="roc")
    plot_curves(out_dir / f"{name}_pr.png", {k: c["pr"] for k, c in curves.items()}, kind="pr")
    return result


def _tested(f: dict) -> str:
    tested = f.get("tested")
    return "n/a" if tested is None else "yes" if tested else f"**no**: {f['untested_because']}"


def report(result: dict) -> str:
    """A result as markdown: title, table, findings (with whether the regime tests them), positive controls."""
    steps = result.get("steps_text") or f"{result['scale']['steps']} training steps per network"
    binning = (f" Intervals use per-frame histograms over {TABLE_BINS} bins; their metrics of all frames are "
               f"within {result['binning']:.2f} points of the exact ones." if "binning" in result else "")
    lines = [f"## {result['title']}", "", *([result["description"], ""] if result.get("description") else []),
             markdown(result["table"]), "",
             f"`{result['name']}`; {steps}; {result['seeds']}.{binning} A finding is tested only where every network "
             f"of the rows it compares reaches {COMPETENT_MIOU:.0f}% mIoU.",
             "", "| paper's finding | holds here? | tested? | evidence |", "|---|---|---|---|"]
    lines += [f"| {f['claim']} | {'yes' if f['holds'] else '**no**'} | {_tested(f)} | {f['evidence']} |"
              for f in result["findings"]]
    return "\n".join(lines + control_lines(result.get("controls", [])))


def control_lines(controls: Sequence[dict]) -> list[str]:
    """The markdown lines of the positive ``controls`` (``Finding`` dicts; none without any)."""
    if not controls:
        return []
    lines = ["", "Positive controls (built so that the mechanism must help; a failing control points at a bug, "
             "not at the paper):", "", "| positive control | passes? | evidence |", "|---|---|---|"]
    return lines + [f"| {f['claim']} | {'yes' if f['holds'] else '**no: points at a bug**'} | {f['evidence']} |"
                    for f in controls]


# ---------------------------------------------------------------- findings

LOWER_IS_BETTER = {"fpr95"}
NAMES = {"ap": "AP", "auroc": "AUROC", "fpr95": "FPR95", "miou": "mIoU", "f1": "mean F1"}


def comparison(values: dict, a: str, b: str, metric: str, lower: bool | None = None) -> dict:
    """``a`` against ``b`` in ``metric``: ``{a, b, metric, difference (a - b of the means), low, high,
    better}``. With replicates on both rows (paired), ``[low, high]`` is the 95% interval of the paired
    difference and ``better`` says it lies entirely on the paper's side of 0 (above; below where ``lower``,
    by default for the metrics of ``LOWER_IS_BETTER``). Without, ``low``/``high`` are None and ``better``
    says the difference of means exceeds the larger std over seeds (0 for one seed)."""
    x, y = values[a][metric], values[b][metric]
    sign = -1.0 if (metric in LOWER_IS_BETTER if lower is None else lower) else 1.0
    out = {"a": a, "b": b, "metric": metric, "difference": x - y, "low": None, "high": None}
    if "replicates" in values[a] and "replicates" in values[b]:
        low, high = interval(values[a]["replicates"][metric] - values[b]["replicates"][metric])
        return {**out, "low": low, "high": high, "better": bool(sign * low > 0 and sign * high > 0)}
    spread = max(values[a].get(f"{metric}_std", 0.0), values[b].get(f"{metric}_std", 0.0))
    return {**out, "better": bool(sign * (x - y) > spread)}


def _better(values: dict, a: str, b: str, metric: str) -> bool:
    """``a`` beats ``b`` in ``metric`` (``comparison``)."""
    return comparison(values, a, b, metric)["better"]


def _delta(c: dict) -> str:
    """A comparison's difference and interval, e.g. "Δ +7.30 [+2.10, +12.00]"."""
    interval_text = "" if c["low"] is None else f" [{c['low']:+.2f}, {c['high']:+.2f}]"
    return f"Δ {c['difference']:+.2f}{interval_text}"


def _pair(values: dict, a: str, b: str, metric: str) -> str:
    text = f"{NAMES[metric]} {_cell(values[a], metric)} vs {_cell(values[b], metric)}"
    return text + (f", {_delta(comparison(values, a, b, metric))}" if "replicates" in values[a] else "")


def _finding(claim: str, holds: bool, evidence: str, values: dict, pairs: Sequence[tuple[str, str, str]]) -> Finding:
    """A finding comparing ``pairs`` of ``(a, b, metric)``, with their rows and intervals."""
    rows = list(dict.fromkeys(label for a, b, _ in pairs for label in (a, b)))
    return Finding(claim, holds, evidence, rows, [comparison(values, a, b, m) for a, b, m in pairs],
                   *competence(values, rows))


def improves(values: dict, new: str, old: str, metrics: Sequence[str] = ("ap",), claim: str | None = None) -> Finding:
    """``new`` is better than ``old`` in every metric of ``metrics``."""
    holds = all(_better(values, new, old, m) for m in metrics)
    evidence = ", ".join(_pair(values, new, old, m) for m in metrics)
    return _finding(claim or f"{new} beats {old} in {'/'.join(NAMES[m] for m in metrics)}", holds, evidence,
                    values, [(new, old, m) for m in metrics])


def worse(values: dict, new: str, old: str, metric: str, claim: str) -> Finding:
    """``new`` is worse than ``old`` in ``metric``."""
    return _finding(claim, _better(values, old, new, metric), _pair(values, new, old, metric), values,
                    [(new, old, metric)])


def not_better(values: dict, new: str, old: str, metric: str, claim: str) -> Finding:
    """``new`` does not improve on ``old`` in ``metric``: the paired interval does not lie on the better side
    of 0 (equal or worse)."""
    return _finding(claim, not _better(values, new, old, metric), _pair(values, new, old, metric), values,
                    [(new, old, metric)])


def _chain(values: dict, pairs: Sequence[tuple[str, str]], metric: str) -> str:
    """The differences of ``pairs`` with their intervals ("" without replicates)."""
    if not all("replicates" in values[x] for pair in pairs for x in pair):
        return ""
    return "; " + ", ".join(f"{a} − {b} {_delta(comparison(values, a, b, metric))}" for a, b in pairs)


def ordered(values: dict, labels: Sequence[str], metric: str = "ap", claim: str | None = None) -> Finding:
    """``labels`` strictly increase in quality in this order."""
    pairs = [(b, a) for a, b in zip(labels, labels[1:])]
    holds = all(_better(values, b, a, metric) for b, a in pairs)
    evidence = ", ".join(f"{label} {_cell(values[label], metric)}" for label in labels)
    return _finding(claim or f"{NAMES[metric]}: {' < '.join(labels)}", holds,
                    f"{NAMES[metric]}: {evidence}{_chain(values, pairs, metric)}", values,
                    [(b, a, metric) for b, a in pairs])


def best(values: dict, winner: str, among: Sequence[str], metric: str = "ap", claim: str | None = None) -> Finding:
    """``winner`` is the best of ``among``."""
    pairs = [(winner, other) for other in among if other != winner]
    holds = all(_better(values, winner, other, metric) for _, other in pairs)
    evidence = ", ".join(f"{label} {_cell(values[label], metric)}" for label in among)
    return _finding(claim or f"{winner} has the best {NAMES[metric]}", holds,
                    f"{NAMES[metric]}: {evidence}{_chain(values, pairs, metric)}", values,
                    [(winner, other, metric) for _, other in pairs])
