"""MMF Tables 1-4 on synthetic scenes, inside the road ROI.

- Table 2 (ablation): the plain resynthesis net, + assistant maps [A, D] and the RGB-D semantics,
  + the superpixel post-processor of Eq. 6, both (MMF), and MMF without the depth semantics Ŝ_D or
  without the uncertainty maps [A, D] (each its own dissimilarity net; "without both" is the plain
  net with the post-processor); the post-processor on connected superpixels and on SLIC of the
  anomaly map (the text's reading, docs/papers/mmf.md#slic-superpixels);
- Table 1: softmax entropy and the uncertainty scores the library has (MSP, max logit, SML) on the
  segmenter of the same pipeline and frames; AP, FPR95 and SMIYC's mean component F1;
- Table 3: the time of each module per frame at the working size, measured in this run;
- Table 4: the lighter synthesizer (a SPADE GAN) against the class-mean synthesizer, with the
  segmenter and RGB-D net shared and both dissimilarity nets retrained on its resynthesis;
- a positive control: the plain net fed the resynthesis of the ground-truth semantics (anomalies
  and void painted as unknown) must beat the same net fed the prediction's resynthesis.

Every part is trained by ``jaxanom.app.mmf_pipeline`` with the budget of ``PRESET`` (below
``jaxanom demo mmf``'s). AP is Eq. 7's envelope (VOC all-point) AP; FPR95 and AUROC as elsewhere;
mean F1 is ``metrics.components`` on the obstacle track. Rows are compared paired, as in the other
tables: one hierarchical bootstrap over seeds and scored frames resamples every row's per-frame
histograms (AP, FPR95, AUROC) and per-frame component counts (mean F1, at each row's pooled best-F1
threshold). A comparison whose rows have identical outputs in every seed (identical ROC and PR curves)
is reported as untested, never as holding.

    python -m experiments --only mmf_table2
"""
from __future__ import annotations

import dataclasses
import hashlib
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from experiments.common import (COMPETENT_MIOU, HERE, RUNS, TABLE_BINS, Scale, _batches, _cell, _row_json, _tested,
                                _thin, aggregate, best, improves, not_better, score_histograms, seed_scales,
                                seeds_text)
from experiments.jobs import Job
from experiments.stats import binned_auroc, binned_metrics, hierarchical, hierarchical_draws
from jaxanom import sml
from jaxanom.app.mmf_experiment import MMFDemoConfig, evaluation_frames
from jaxanom.app.evaluate import anomaly_results, class_statistics, predictions, predictor, segmentation_results
from jaxanom.app.experiment import frames
from jaxanom.app.mmf_pipeline import DISSIM_NETS, DISSIM_VARIANTS, MMFConfig, MMFPipeline, module_calls, scored_batch
from jaxanom.data import SyntheticScenes
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.metrics import confusion_matrix, miou
from jaxanom.superpixels import scaled_step

NAME = "mmf_table2"
TITLE = "MMF Tables 1-4: assistant maps, depth, post-processor, timings and synthesizers, in the road ROI"

# The demo's pipeline (MMFConfig()) with fewer steps and frames for the nets after the segmenter, and
# every ablation net. The segmenter is the competent baseline of the other tables (docs/decisions/baselines.md; Scale's
# defaults: deeplabv3plus_small, 2000 steps on 512 scenes, 60-65% mIoU); the demo's reaches 17%. The
# RGB-D net's mIoU on the validation frames over seeds 0 and 1: 150 steps 21% (on the scored frames),
# 2000 steps 59.1 ± 0.8%, 4000 steps (~3 min a seed on 2 loaded cores) 63.8 ± 1.7%.
_SEG, _COMPETENT = MMFConfig().segmenter, Scale()
PRESET = dataclasses.replace(
    MMFConfig(), segmenter=dataclasses.replace(
        _SEG, model=_COMPETENT.model, train_frames=_COMPETENT.train_frames,
        train=dataclasses.replace(_SEG.train, steps=_COMPETENT.steps, eval_every=_COMPETENT.steps,
                                  save_every=_COMPETENT.steps, optim=dataclasses.replace(_SEG.train.optim, warmup_steps=30))),
    rgbd_steps=4000, dissim_steps=200, dissim_frames=64, dissim_variants=tuple(DISSIM_VARIANTS), gan_steps=200)
ANOMALY_FRAMES = 32
# Seeds of the pipeline: 3 x the table's seed, because a pipeline of seed s draws its segmenter's
# frames from s, its dissimilarity nets' from s + 1 and its anomaly frames from s + 2.
SEED_STRIDE = 3
TRACK = "obstacle"  # SMIYC's component rules for mean F1 (predicted >= 50 px, ground truth >= 10 px)
TIMING_REPEATS = 20

# The paper's Table 1 (percent; in the road ROI): Obstacle Track and Lost and Found, AP / FPR95 / mean F1.
PAPER_TABLE1 = {"Softmax Entropy": ((55.41, 5.28, 11.06), (68.34, 9.53, 18.43)),
                "Resynthesis (w/void)": ((28.29, 15.24, 8.55), (31.11, 16.03, 12.84)),
                "MMF": ((70.93, 4.16, 39.64), (80.04, 5.31, 50.77))}
# The paper's Table 3 (ms per frame, RTX 3090, mean of 100 runs): module -> (MMF, Resynthesis, resolution).
PAPER_TABLE3 = {"segmentation": (686.93, 875.68, "2048x1024"), "synthesis": (105.00, 133.86, "1024x512"),
                "depth": (75.70, None, "1024x512"), "perceptual difference": (7.11, None, "512x256"),
                "dissimilarity": (28.98, 36.95, "512x256"), "total": (903.72, 1046.49, "")}
_TABLE2 = "a Table 2 row (an image in our copy; its numbers are not in the text)"
_TABLE4 = "a Table 4 row (an image in our copy; its numbers are not in the text)"


@dataclasses.dataclass(frozen=True)
class Row:
    """One line: ``method`` (``jaxanom.method_registry``) scored with dissimilarity net ``net`` (``"mmf"`` or a
    variant of ``DISSIM_VARIANTS``) of the pipeline with ``synthesizer``; ``paper``: a key of
    ``PAPER_TABLE1`` or what the paper gives instead; ``slic``: ``MMFConfig`` settings of the post-processor."""

    label: str
    method: str
    net: str = "mmf"
    synthesizer: str = "class_mean"
    paper: str = "not in the paper's tables"
    slic: tuple = ()


ENTROPY, BASE, POST, ASSISTED, FULL = ("entropy", "resynthesis", "resynthesis + post-processor (MMF without both)",
                                       "resynthesis + assistant maps", "MMF (assistant maps + post-processor)")
NO_DEPTH, NO_UNCERTAINTY = "MMF without depth (no Ŝ_D)", "MMF without uncertainty (no [A, D])"
CONTROL = "control: resynthesis of the ground truth"
SPADE_BASE, SPADE_FULL = "SPADE synthesizer: resynthesis", "SPADE synthesizer: MMF"
ROWS = (Row(ENTROPY, "entropy", paper="Softmax Entropy"),
        Row(BASE, "resynthesis", paper="Resynthesis (w/void)"),
        Row(POST, "resynthesis_post", paper=_TABLE2),
        Row(ASSISTED, "mmf_raw", paper=_TABLE2),
        Row(FULL, "mmf", paper="MMF"),
        Row(NO_DEPTH, "mmf", net="no_depth", paper="not in the paper (Table 2 ablates [A, D] and Ŝ_D together)"),
        Row(NO_UNCERTAINTY, "mmf", net="no_uncertainty",
            paper="not in the paper (Table 2 ablates [A, D] and Ŝ_D together)"),
        Row("MSP", "msp"), Row("max logit", "max_logit"), Row("SML", "sml"),
        Row("MMF, connected superpixels", "mmf", slic=(("slic_connectivity", True),)),
        Row("MMF, SLIC on the anomaly map a", "mmf", slic=(("slic_input", "anomaly"),)),
        Row(CONTROL, "mmf_raw", net="truth_resynthesis", paper="a control of ours"),
        Row(SPADE_BASE, "resynthesis", synthesizer="spade", paper=_TABLE4),
        Row(SPADE_FULL, "mmf", synthesizer="spade", paper=_TABLE4))
TABLE2 = (BASE, POST, ASSISTED, FULL)
TABLE1 = (ENTROPY, BASE, FULL, "MSP", "max logit", "SML")
# rows scored by a dissimilarity net fed the RGB-D net's semantics Ŝ_D
DEPTH_ROWS = tuple(row.label for row in ROWS if row.method in ("mmf", "mmf_raw")
                   and {**DISSIM_NETS, **DISSIM_VARIANTS}[row.net][1])
METRICS = ("ap", "fpr95", "auroc", "f1")


def is_smoke(scale: Scale) -> bool:
    """``Scale.smoke()`` (any seed): the test-sized run, which uses ``MMFConfig.quick()``."""
    return dataclasses.replace(scale, seed=0) == Scale.smoke()


def demo_config(scale: Scale) -> MMFDemoConfig:
    """The pipeline and anomaly frames of one seed: ``PRESET`` (``MMFConfig.quick()`` with the
    variant nets and 2 GAN steps for a smoke scale) with every random stream seeded by
    ``SEED_STRIDE * scale.seed``."""
    if scale.cityscapes_root is not None or scale.anomaly is not None:
        raise ValueError("scale: mmf_table2 trains and scores synthetic scenes with disparity only; got "
                         f"cityscapes_root={scale.cityscapes_root!r}, anomaly={scale.anomaly!r}")
    config = (dataclasses.replace(MMFConfig.quick(), dissim_variants=PRESET.dissim_variants, gan_steps=2)
              if is_smoke(scale) else PRESET)
    seg = config.segmenter
    seg = dataclasses.replace(seg, train=dataclasses.replace(seg.train, seed=SEED_STRIDE * scale.seed))
    frames_scored = scale.anomaly_frames if is_smoke(scale) else ANOMALY_FRAMES
    return MMFDemoConfig(pipeline=dataclasses.replace(config, segmenter=seg), anomaly_split=scale.anomaly_split,
                         anomaly_frames=frames_scored)


def build_parts(scale: Scale, runs: Path) -> None:
    """Train (or restore) every part of one seed's two pipelines into ``runs/mmf`` (a ``jobs.Job``)."""
    config = demo_config(scale).pipeline
    for pipeline in (config, spade_config(config)):
        MMFPipeline.build(pipeline, runs / "mmf", progress=False)


def jobs(scale: Scale, seeds: int, runs: Path) -> list[Job]:
    """``build_parts`` of every seed, to run before the table (``python -m experiments --jobs``)."""
    return [Job(f"{NAME} seed {s.seed}", build_parts, (s, runs), 14.0) for s in seed_scales(scale, seeds)]


def spade_config(config: MMFConfig) -> MMFConfig:
    """Table 4's pipeline: ``config`` with the SPADE synthesizer (segmenter and RGB-D net shared)."""
    return dataclasses.replace(config, synthesizer="spade", dissim_variants=())


def fingerprint(curves: dict) -> str:
    """A hash of a row's full ROC and PR curves: equal for rows whose scores rank the pixels alike
    (then AP, FPR95, AUROC and mean F1 are equal too)."""
    digest = hashlib.sha256()
    for kind in ("roc", "pr"):
        for array in curves[kind]:
            digest.update(np.ascontiguousarray(np.asarray(array, np.float64)).tobytes())
    return digest.hexdigest()[:16]


def identical_rows(fingerprints: Sequence[dict]) -> list[list[str]]:
    """Groups (of >= 2 labels) whose fingerprints agree in every seed; ``fingerprints``: one
    ``{label: fingerprint}`` per seed."""
    groups: dict[tuple, list[str]] = {}
    for label in fingerprints[0]:
        groups.setdefault(tuple(seed[label] for seed in fingerprints), []).append(label)
    return [labels for labels in groups.values() if len(labels) > 1]


def _row_values(metrics: dict, miou_value: float, network: str, score: str) -> dict:
    f1 = metrics.get("components", {}).get("f1_mean")
    return {"ap": 100 * metrics["ap"], "auroc": 100 * metrics["auroc"], "fpr95": 100 * metrics["fpr_at_tpr"],
            "f1": float("nan") if f1 is None else 100 * f1, "miou": 100 * miou_value, "network": network,
            "score": score}


def frame_counts(metrics: dict, curves: dict) -> dict:
    """One row's per-frame counts for the paired bootstrap, from ``anomaly_results`` with ``track`` and
    ``keep_curves``: ``histograms`` (F, TABLE_BINS + 1, 2) of its scores (``common.score_histograms``) and
    ``components`` (F, T, 3): TP, FN, FP of each frame at each sIoU threshold."""
    histograms, _ = score_histograms(curves["scores"], curves["labels"])
    components = np.array([[f["components"][k] for k in ("tp", "fn", "fp")] for f in metrics["frames"]], np.int64)
    return {"histograms": histograms, "components": components.transpose(0, 2, 1)}


def _pixel_metrics(histograms: np.ndarray) -> dict[str, np.ndarray]:
    """Percent envelope AP (Eq. 7), FPR95 and AUROC of pooled histograms (..., bins, 2)."""
    binned = binned_metrics(histograms)
    return {"ap": 100 * binned["ap_envelope"], "fpr95": 100 * binned["fpr_at_tpr"],
            "auroc": 100 * binned_auroc(histograms)}


def _mean_f1(counts: np.ndarray) -> dict[str, np.ndarray]:
    """Percent mean F1 over the sIoU thresholds of pooled (..., T, 3) TP, FN, FP counts: F1 = 2 TP /
    (2 TP + FN + FP), NaN where that is 0 / 0 (``metrics.components.component_summary``)."""
    tp, fn, fp = (counts[..., k].astype(np.float64) for k in range(3))
    denominator = 2 * tp + fn + fp
    return {"f1": 100 * np.where(denominator > 0, 2 * tp / np.maximum(denominator, 1), np.nan).mean(-1)}


def paired_replicates(per_seed: Sequence[dict]) -> dict:
    """``{label: {metric: (R,)}}``: the bootstrap replicates of every row (``per_seed[s][label]``: its
    ``frame_counts`` in seed s), all drawn with one ``stats.hierarchical_draws`` over seeds and frames."""
    first = next(iter(per_seed[0]))
    draws = hierarchical_draws({"anomaly": [len(seed[first]["histograms"]) for seed in per_seed]})
    return {label: {**hierarchical([seed[label]["histograms"] for seed in per_seed], draws, "anomaly", _pixel_metrics),
                    **hierarchical([seed[label]["components"] for seed in per_seed], draws, "anomaly", _mean_f1)}
            for label in per_seed[0]}


def quality(cached: list, pipe: MMFPipeline, spade: MMFPipeline, num_classes: int) -> dict:
    """Each network's quality on the scored frames (``cached``: ``(frames, maps)`` of ``_maps``), on
    their known-class pixels (the ground-truth ``semantic``; anomalies are 255 there): the
    segmenter's and the RGB-D net's mIoU, and each synthesizer's mean absolute error (RGB in [0, 1],
    percent) when it resynthesizes the ground-truth semantics (anomalies painted as unknown)."""
    total = {"segmenter": 0, "rgbd": 0}
    errors = {"class_mean": [], "spade": []}
    for chunk, maps in cached:
        semantic = np.stack([f["semantic"] for f in chunk]).astype(np.int32)
        image = np.stack([f["image"] for f in chunk]) / 255.0
        for name, key in (("segmenter", "prediction"), ("rgbd", "prediction_depth")):
            total[name] = total[name] + np.asarray(confusion_matrix(maps[key], semantic, num_classes, 255), np.int64)
        for name, synthesizer in (("class_mean", pipe.synthesizer), ("spade", spade.synthesizer)):
            errors[name].append(np.abs(np.asarray(synthesizer.synthesize_batch(semantic)) - image).mean(axis=(1, 2, 3)))
    return {"segmenter_miou": 100 * float(miou(total["segmenter"])), "rgbd_miou": 100 * float(miou(total["rgbd"])),
            **{f"{k}_error": 100 * float(np.concatenate(v).mean()) for k, v in errors.items()}}


def rgbd_validation_miou(pipe: MMFPipeline, count: int) -> float:
    """The RGB-D net's mIoU (percent) on ``count`` synthetic validation frames with disparity, drawn from
    the segmenter's seed (the frames on which the segmenter's mIoU is measured, with their disparity)."""
    seg = pipe.config.segmenter
    source = SyntheticScenes("val", count, seg.train.seed, height=seg.height, width=seg.width, disparity=True)
    total = 0
    for start in range(0, count, seg.batch_size):
        chunk = [source[i] for i in range(start, min(start + seg.batch_size, count))]
        labels = np.stack([f["label"] for f in chunk]).astype(np.int32)
        total = total + np.asarray(confusion_matrix(pipe.semantics(chunk)[1], labels, seg.num_classes, 255), np.int64)
    return 100 * float(miou(total))


def timings(pipe: MMFPipeline, spade: MMFPipeline, frame: dict, repeats: int) -> dict:
    """Milliseconds per frame of each module (``mmf_pipeline.module_calls``, median of ``repeats``
    after a warm-up call), the SPADE synthesizer's and the sum of MMF's modules, with the device."""
    from benchmarks.timing import environment, median_ms

    ms = {name: median_ms(call, repeats=repeats, warmup=1) for name, call in module_calls(pipe, [frame]).items()}
    ms["synthesis (SPADE)"] = median_ms(module_calls(spade, [frame])["synthesis"], repeats=repeats, warmup=1)
    ms["total"] = sum(v for k, v in ms.items() if k != "synthesis (SPADE)")
    return {"ms": ms, "environment": environment(), "repeats": repeats}


def _maps(pipe: MMFPipeline, source, batch_size: int) -> list[tuple[list, dict]]:
    """``(frames, pipe.maps(frames))`` per batch of ``source``."""
    chunks = [[source[i] for i in range(start, min(start + batch_size, len(source)))]
              for start in range(0, len(source), batch_size)]
    return [(chunk, pipe.maps(chunk)) for chunk in chunks]


def _score(cached: list, rows: Sequence[Row], stats) -> tuple[dict, dict]:
    """``anomaly_results`` of ``rows`` (one synthesizer and SLIC setting) on the maps of ``_maps``,
    which each dissimilarity net's rows read."""
    metrics, curves = {}, {}
    for net in dict.fromkeys(row.net for row in rows):
        methods = list(dict.fromkeys(row.method for row in rows if row.net == net))
        m, c = anomaly_results((scored_batch(chunk, maps, net) for chunk, maps in cached), methods, stats=stats,
                               ap_convention="envelope", keep_curves=True, track=TRACK)
        for row in rows:
            if row.net == net:
                metrics[row.label], curves[row.label] = m[row.method], c[row.method]
    return metrics, curves


def seed_values(scale: Scale, runs: Path, log: Callable, time_modules: bool = False) -> tuple[dict, dict, dict]:
    """One seed: ``(values[label], curves[label], info)``; ``info`` has the part keys, fingerprints,
    network quality, seconds and, with ``time_modules``, the module timings."""
    config = demo_config(scale)
    pipe_config, seg = config.pipeline, config.pipeline.segmenter
    start = time.perf_counter()
    stamp = lambda text: log(f"  [{time.perf_counter() - start:.0f} s] {text}")  # noqa: E731
    pipe = MMFPipeline.build(pipe_config, runs / "mmf", progress=False, log=stamp)
    spade = MMFPipeline.build(spade_config(pipe_config), runs / "mmf", progress=False, log=stamp)
    built = time.perf_counter() - start
    predict = predictor(*pipe.segmenter)
    stats = class_statistics(predict, _batches(frames(seg, "train", scale.stats_frames), seg.batch_size))
    stats = sml.stats_finalize(stats, missing="pooled", policy="none")
    miou_value = segmentation_results(predictions(predict, _batches(frames(seg, "val", scale.val_frames),
                                                                    seg.batch_size)), seg.num_classes)["miou"]
    source = evaluation_frames(config)
    metrics, curves = {}, {}
    groups: dict[tuple, list[Row]] = {}
    for row in ROWS:
        groups.setdefault((row.synthesizer, row.slic), []).append(row)
    for (synthesizer, slic), rows in groups.items():
        base = pipe if synthesizer == "class_mean" else spade
        scorer = dataclasses.replace(base, config=dataclasses.replace(base.config, **dict(slic)))
        cached = _maps(scorer, source, pipe_config.batch_size)
        if synthesizer == "class_mean" and not slic:
            stamp("network quality")
            network_quality = {**quality(cached, pipe, spade, seg.num_classes),
                               "rgbd_val_miou": rgbd_validation_miou(pipe, scale.val_frames)}
        m, c = _score(cached, rows, stats)
        metrics.update(m)
        curves.update(c)
    keys = {"segmenter": f"segmenter-{pipe_config.part_key('segmenter')}",
            **{name: f"dissimilarity-{name}-{pipe_config.part_key('dissimilarity')}"
               for name in ("mmf", "resynthesis", *pipe_config.dissim_variants)},
            **{f"spade {name}": f"dissimilarity-{name}-{spade.config.part_key('dissimilarity')}"
               for name in ("mmf", "resynthesis")}}
    values, thin, prints, counts = {}, {}, {}, {}
    for row in ROWS:
        net = {"resynthesis": "resynthesis", "resynthesis_post": "resynthesis"}.get(row.method, row.net)
        part = "segmenter" if row.method in ("entropy", "msp", "max_logit", "sml") else (
            f"spade {net}" if row.synthesizer == "spade" else net)
        values[row.label] = _row_values(metrics[row.label], miou_value, keys[part], row.method)
        counts[row.label] = frame_counts(metrics[row.label], curves[row.label])
        values[row.label]["binning"] = max(abs(_pixel_metrics(counts[row.label]["histograms"].sum(0))[k]
                                               - values[row.label][k]) for k in ("ap", "fpr95", "auroc"))
        thin[row.label] = {"roc": _thin(*curves[row.label]["roc"]), "pr": _thin(*curves[row.label]["pr"])}
        prints[row.label] = fingerprint(curves[row.label])
    info = {"keys": keys, "config": pipe_config.to_dict(), "fingerprints": prints, "quality": network_quality,
            "frames": counts}
    if time_modules:
        stamp("module timings")
        info["timings"] = timings(pipe, spade, source[0], TIMING_REPEATS)
    info["seconds"] = {"build": built, "total": time.perf_counter() - start}
    log(f"  {NAME} seed {scale.seed}: pipelines built in {built:.0f} s, in all {info['seconds']['total']:.0f} s")
    return values, thin, info


# ---------------------------------------------------------------- findings

def competence(segmenter: float | None, rgbd: float | None) -> tuple[bool | None, str]:
    """``(tested, why not)`` of a claim from the mIoU of the segmenter (None: unknown) and, where the claim
    reads Ŝ_D, of the RGB-D net (None: it does not, or unknown)."""
    if segmenter is None:
        return None, ""
    reasons = [f"the pipeline's segmenter reaches {segmenter:.1f}% mIoU (< {COMPETENT_MIOU:.0f}%), and its maps "
               "and resynthesis feed every row"] if segmenter < COMPETENT_MIOU else []
    if rgbd is not None and rgbd < COMPETENT_MIOU:
        reasons.append(f"the RGB-D net, whose semantics Ŝ_D a compared row reads, reaches {rgbd:.1f}% mIoU (< "
                       f"{COMPETENT_MIOU:.0f}%)")
    return not reasons, "; ".join(reasons)


def findings(v: dict, identical: Sequence[Sequence[str]] = (), better_synthesizer: str = "class_mean",
             rgbd_miou: float | None = None) -> list[dict]:
    """The paper's claims (Tables 1, 2, 4; §IV-C) and the control, each ``{claim, holds, evidence, rows,
    intervals, status, control, tested, untested_because}`` (``common.Finding``'s fields, paired where the
    rows carry ``"replicates"``; ``tested``: the segmenter, whose maps feed every row,
    reaches ``COMPETENT_MIOU``; None without its mIoU); ``status`` is ``"untested"`` (and ``holds`` False) where two of the rows a
    claim compares are in one group of ``identical`` (same outputs in every seed: nothing changed).
    ``better_synthesizer``: the one with the lower resynthesis error (``quality``). ``rgbd_miou``: the
    RGB-D net's mIoU on the validation frames (``rgbd_validation_miou``); a claim comparing a row scored
    by a net fed its semantics Ŝ_D (``DEPTH_ROWS``) is tested only where it too reaches ``COMPETENT_MIOU``."""
    better, lighter = (FULL, SPADE_FULL) if better_synthesizer == "class_mean" else (SPADE_FULL, FULL)
    checks = [
        improves(v, ASSISTED, BASE, ("ap",), "the assistant maps raise the resynthesis net's AP"),
        not_better(v, ASSISTED, BASE, "fpr95", "the assistant maps do not clearly lower FPR95"),
        improves(v, POST, BASE, ("fpr95",), "the post-processor lowers the resynthesis net's FPR95"),
        best(v, FULL, TABLE2, "ap", "both together (MMF) have the best AP of the ablation"),
        best(v, FULL, TABLE2, "fpr95", "both together (MMF) have the best FPR95 of the ablation"),
        improves(v, FULL, NO_DEPTH, ("ap",), "the depth semantics Ŝ_D add to MMF's AP (§IV-B: they complement)"),
        improves(v, FULL, NO_UNCERTAINTY, ("ap",), "the uncertainty maps [A, D] add to MMF's AP"),
        improves(v, ENTROPY, BASE, ("ap",), "Table 1: entropy beats the plain resynthesis net in AP"),
        improves(v, FULL, ENTROPY, ("ap", "fpr95"), "Table 1: MMF beats softmax entropy in AP and FPR95"),
        best(v, FULL, TABLE1, "ap", "Table 1: MMF has the best AP of all rows"),
        best(v, FULL, TABLE1, "f1", "Table 1: MMF has the best mean F1 of all rows"),
        improves(v, SPADE_FULL, SPADE_BASE, ("ap",), "Table 4: with the lighter synthesizer MMF still beats Resynthesis"),
        improves(v, better, lighter, ("ap",), "Table 4: the better synthesizer (lower resynthesis error) gives the "
                                              "higher AP"),
    ]
    control = improves(v, CONTROL, BASE, ("ap",), "control: the resynthesis net fed the ground truth's resynthesis "
                                                  "beats it fed the prediction's (must hold)")
    segmenter = v.get(ENTROPY, {}).get("miou")  # every row carries its pipeline's segmenter mIoU
    out = []
    for finding, is_control in [(c, False) for c in checks] + [(control, True)]:
        tested, why = competence(segmenter, rgbd_miou if set(finding.rows) & set(DEPTH_ROWS) else None)
        same = [g for g in identical if sum(label in g for label in finding.rows) >= 2]
        status = "untested" if same else ("holds" if finding.holds else "fails")
        prefix = f"untested: {' = '.join(same[0])} have identical outputs in every seed; " if same else ""
        out.append({**dataclasses.asdict(finding), "holds": status == "holds", "evidence": prefix + finding.evidence,
                    "status": status, "control": is_control, "tested": tested, "untested_because": why})
    return out


# ---------------------------------------------------------------- report

def _paper_cell(row: Row) -> str:
    if row.paper not in PAPER_TABLE1:
        return row.paper
    (oa, of, o1), (la, lf, l1) = PAPER_TABLE1[row.paper]
    return f"{row.paper}: OT {oa:.2f} / {of:.2f} / {o1:.2f}; L&F {la:.2f} / {lf:.2f} / {l1:.2f}"


def _spread(values: Sequence[float]) -> str:
    xs = np.asarray(values, np.float64)
    return f"{xs.mean():.2f}" if len(xs) < 2 else f"{xs.mean():.2f} ± {xs.std(ddof=1):.2f}"


def report(result: dict) -> str:
    """The markdown of a result: the table with the paper's numbers, network quality, timings, findings."""
    rows = {row.label: row for row in ROWS}
    lines = [f"## {result['title']}", "", result["description"], "",
             "| row | score | net | AP ↑ | FPR95 ↓ | AUROC ↑ | mean F1 ↑ | paper: AP / FPR95 / mean F1 |",
             "|---|---|---|---|---|---|---|---|"]
    for v in result["table"]:
        lines.append(f"| {v['label']} | `{v['score']}` | `{v['network']}` | {_cell(v, 'ap')} | {_cell(v, 'fpr95')} | "
                     f"{_cell(v, 'auroc')} | {_cell(v, 'f1')} | {_paper_cell(rows[v['label']])} |")
    q = result["quality"]
    lines += ["", f"`{result['name']}`; {result['steps_text']}; {result['seeds']}. Intervals use per-frame "
              f"histograms over {TABLE_BINS} bins (their AP, FPR95 and AUROC of all frames are within "
              f"{result['binning']:.2f} points of the exact ones) and per-frame component counts.", "",
              "Each network's quality (mean ± std over seeds): the segmenter's mIoU on "
              f"{result['scale']['val_frames']} validation frames {_cell(result['table'][0], 'miou')}% (our bar "
              f"for a competent baseline is 60%: {'met' if result['table'][0]['miou'] >= 60 else '**not met**'}), the "
              f"RGB-D net's on the same frames with disparity {_spread(q['rgbd_val_miou'])}% (the bar "
              f"{'met' if np.mean(q['rgbd_val_miou']) >= COMPETENT_MIOU else '**not met**'}; a claim comparing a row "
              "whose net reads its semantics Ŝ_D is tested only where it is met); on the known-class pixels of the "
              f"scored frames, segmenter mIoU {_spread(q['segmenter_miou'])}% and RGB-D net mIoU "
              f"{_spread(q['rgbd_miou'])}%; resynthesis of their ground-truth semantics, mean absolute RGB error: "
              f"class means {_spread(q['class_mean_error'])}%, SPADE {_spread(q['spade_error'])}%; the dissimilarity "
              "nets' quality is their rows above."]
    t = result["timings"]
    if t is None:
        lines += ["", "Table 3 (module timings): not measured at the smoke scale."]
    else:
        lines += table3(t, result["size"])
    lines += ["", "| paper's finding | holds here? | tested? | evidence |", "|---|---|---|---|"]
    marks = {"holds": "yes", "fails": "**no**", "untested": "untested"}
    lines += [f"| {'**' + f['claim'] + '**' if f['control'] else f['claim']} | {marks[f['status']]} | {_tested(f)} | "
              f"{f['evidence']} |" for f in result["findings"] + result["controls"]]
    same = result["identical_rows"]
    lines += ["", "Rows with identical outputs in every seed (their comparisons are untested): "
              + ("; ".join(" = ".join(g) for g in same) if same else "none") + "."]
    return "\n".join(lines)


def table3(t: dict, size: str) -> list[str]:
    """Markdown lines of the module timings ``t`` (``timings``) beside the paper's Table 3."""
    env = t["environment"]
    lines = ["", f"Table 3 (ms per frame, batch 1, median of {t['repeats']} calls after a warm-up, each module "
              f"jitted alone; {env['device']}, {env.get('cpu', '')}, shared with other jobs; jax {env['jax']}, "
              f"flax {env.get('flax', '?')}, numpy {env.get('numpy', '?')}; working size {size}). The "
              "paper's: NVIDIA RTX 3090, mean of 100 runs, each module at its own resolution.", "",
              "| module | here (ms) | paper MMF (ms) | paper Resynthesis (ms) | paper's resolution |", "|---|---|---|---|---|"]
    for name, ms in t["ms"].items():
        paper = PAPER_TABLE3.get(name)
        cells = ("-", "-", "-") if paper is None else (f"{paper[0]:.2f}", "-" if paper[1] is None else
                                                       f"{paper[1]:.2f}", paper[2] or "-")
        lines.append(f"| {name} | {ms:.2f} | {' | '.join(cells)} |")
    return lines


def run(scale: Scale, seeds: int, out_dir: Path = HERE, runs: Path = RUNS, log: Callable = print,
        description: str = "") -> dict:
    """Every seed, aggregated; writes ``mmf_table2.json/.md/_roc.png/_pr.png``."""
    from jaxanom.viz import plot_curves

    log(f"{NAME}: {TITLE}")
    start = time.perf_counter()
    scales = seed_scales(scale, seeds)
    # one architecture: its modules are timed once, in the first seed (not at the smoke scale: compiling only)
    results = [seed_values(s, runs, log, time_modules=i == 0 and not is_smoke(s)) for i, s in enumerate(scales)]
    values, curves, infos = aggregate([r[0] for r in results], (*METRICS, "miou")), results[0][1], [r[2] for r in results]
    for label, replicates in paired_replicates([i["frames"] for i in infos]).items():
        values[label]["replicates"] = replicates
    config = demo_config(scales[0])
    seg, p = config.pipeline.segmenter, config.pipeline
    used = [dataclasses.replace(s, height=seg.height, width=seg.width, train_frames=seg.train_frames,
                                steps=seg.train.steps, batch_size=seg.batch_size,
                                anomaly_frames=config.anomaly_frames) for s in scales]
    minutes = ", ".join(f"{i['seconds']['total'] / 60:.1f}" for i in infos)
    total = (time.perf_counter() - start) / 60
    description = (
        f"{description} Sizes: {seg.height} x {seg.width} frames; segmenter ({seg.model}) on {seg.train_frames} scenes; RGB-D net "
        f"({p.rgbd_backbone}); {2 + len(p.dissim_variants)} dissimilarity nets with the class-mean synthesizer "
        f"(width x {p.dissim_width:g}; MMF, the plain resynthesis net, {', '.join(p.dissim_variants)}) and 2 with "
        f"the SPADE synthesizer (nf {p.gan_nf}, n {p.gan_upsamples}), each on {p.dissim_frames} other scenes with "
        f"up to {p.void_objects} void clutter objects; SLIC step {p.slic_step or scaled_step((seg.height, seg.width))} "
        f"px on the {p.slic_input} unless the row says otherwise; {config.anomaly_frames} `{config.anomaly_split}` "
        f"frames scored in the road ROI; mean F1 on SMIYC's {TRACK} track (predicted components >= 50 px, "
        f"ground-truth ones >= 10 px: strict at this size). The paper's numbers are Table 1's on Obstacle Track "
        f"(OT) and Lost and Found (L&F), real frames at 2048 x 1024 with a Cityscapes-trained DeepLabV3+, in the "
        f"road ROI; its Tables 2 and 4 are images whose numbers are not in our text copy (the text gives Table 2's "
        f"base row, which is Table 1's Resynthesis (w/void)). Pipeline seed = {SEED_STRIDE} x table seed. Run time "
        f"of the invocation that wrote this table: {total:.1f} min on a shared 2-core CPU (minutes per seed: "
        f"{minutes}; parts already in the runs folder are restored, not retrained).")
    steps = (f"training steps: segmenter {seg.train.steps}, RGB-D net {p.rgbd_steps}, SPADE GAN {p.gan_steps}, "
             f"every dissimilarity net {p.dissim_steps}")
    same = identical_rows([i["fingerprints"] for i in infos])
    quality_keys = infos[0]["quality"]
    better = "class_mean" if (np.mean([i["quality"]["class_mean_error"] for i in infos])
                              <= np.mean([i["quality"]["spade_error"] for i in infos])) else "spade"
    rgbd_miou = float(np.mean([i["quality"]["rgbd_val_miou"] for i in infos]))
    claims = findings(values, same, better, rgbd_miou)  # the paper's findings, then the control (counted apart)
    result = {"name": NAME, "title": TITLE, "description": description.strip(),
              "table": [_row_json(k, v) for k, v in values.items()], "scale": dataclasses.asdict(used[0]),
              "findings": [f for f in claims if not f["control"]], "controls": [f for f in claims if f["control"]],
              "identical_rows": same,
              "networks": {k: {"part": part, "mmf_config": i["config"]} for i in infos for part, k in i["keys"].items()},
              "seeds": seeds_text(used), "num_seeds": len(used), "paired": True, "steps_text": steps,
              "binning": max(v["binning"] for v in values.values()),
              "quality": {k: [i["quality"][k] for i in infos] for k in quality_keys},
              "timings": infos[0].get("timings"), "size": f"{seg.height} x {seg.width}", "minutes": total}
    result["report"] = report(result)
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / f"{NAME}.json", result)
    write_bytes_atomic(out_dir / f"{NAME}.md", (result["report"] + "\n").encode())
    plot_curves(out_dir / f"{NAME}_roc.png", {k: c["roc"] for k, c in curves.items()}, kind="roc")
    plot_curves(out_dir / f"{NAME}_pr.png", {k: c["pr"] for k, c in curves.items()}, kind="pr")
    return result


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
