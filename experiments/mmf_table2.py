"""MMF Tables 1 and 2 on synthetic scenes, inside the road ROI: the ablation (the plain
resynthesis net, + assistant maps [A, D] and the RGB-D semantics, + the superpixel post-processor
of Eq. 6, both) against softmax entropy, and Table 1's structure with the uncertainty scores the
library has (MSP, max logit, SML) on the segmenter of the same pipeline and the same frames.
Every part is trained by ``jaxanom.app.mmf_pipeline`` (segmenter, RGB-D net, class-mean synthesizer,
two dissimilarity nets with void clutter as anomaly) with a smaller budget than ``jaxanom demo
mmf`` so that three seeds fit in about 30 minutes on 2 shared CPU cores; see ``PRESET``. AP here
is Eq. 7's envelope (VOC all-point) AP, not the step sum of the other tables; FPR95 and AUROC as
elsewhere. mIoU is the segmenter's on validation frames (every row shares it).

    python -m experiments --only mmf_table2
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable

from experiments.common import (HERE, RUNS, Finding, Scale, _batches, _thin, best, improves, not_better,
                                over_seeds, write_table)
from jaxanom import sml
from jaxanom.app.evaluate import anomaly_results, class_statistics, predictions, predictor, segmentation_results
from jaxanom.app.experiment import frames
from jaxanom.app.demos.mmf import MMFDemoConfig, evaluation_frames
from jaxanom.app.mmf_pipeline import scored_batches
from jaxanom.app.mmf_pipeline import MMFConfig, MMFPipeline
from jaxanom.superpixels import scaled_step

NAME = "mmf_table2"
TITLE = "MMF Tables 1-2: assistant maps and post-processor, in the road ROI"

# The demo's pipeline (MMFConfig()) with fewer steps and frames: ~10 min per seed on loaded cores.
_SEG = MMFConfig().segmenter
PRESET = dataclasses.replace(
    MMFConfig(), segmenter=dataclasses.replace(_SEG, train=dataclasses.replace(_SEG.train, steps=300)),
    rgbd_steps=150, dissim_steps=200, dissim_frames=64)
ANOMALY_FRAMES = 32
# Seeds of the pipeline: 3 x the table's seed, because a pipeline of seed s draws its segmenter's
# frames from s, its dissimilarity nets' from s + 1 and its anomaly frames from s + 2.
SEED_STRIDE = 3

# (label, method, assistant maps, post-processor); the first five are Table 2, all of them Table 1's structure.
ROWS = (("entropy", "entropy", "-", "-"),
        ("resynthesis", "resynthesis", "no", "no"),
        ("resynthesis + post-processor", "resynthesis_post", "no", "yes"),
        ("resynthesis + assistant maps", "mmf_raw", "yes", "no"),
        ("MMF (assistant maps + post-processor)", "mmf", "yes", "yes"),
        ("MSP", "msp", "-", "-"),
        ("max logit", "max_logit", "-", "-"),
        ("SML", "sml", "-", "-"))
# MMF's post-processor with other superpixels (issue 20): (label, MMFConfig settings); scored as `mmf`
SLIC_VARIANTS = (("MMF, connected superpixels", {"slic_connectivity": True}),
                 ("MMF, SLIC on the anomaly map a", {"slic_input": "anomaly"}))
BASE, POST, ASSISTED, FULL = (row[0] for row in ROWS[1:5])
TABLE2 = (BASE, POST, ASSISTED, FULL)


def is_smoke(scale: Scale) -> bool:
    """``Scale.smoke()`` (any seed): the test-sized run, which uses ``MMFConfig.quick()``."""
    return dataclasses.replace(scale, seed=0) == Scale.smoke()


def demo_config(scale: Scale) -> MMFDemoConfig:
    """The pipeline and anomaly frames of one seed: ``PRESET`` (``MMFConfig.quick()`` for a smoke
    scale) with every random stream seeded by ``SEED_STRIDE * scale.seed``."""
    if scale.cityscapes_root is not None or scale.anomaly is not None:
        raise ValueError("scale: mmf_table2 trains and scores synthetic scenes with disparity only; got "
                         f"cityscapes_root={scale.cityscapes_root!r}, anomaly={scale.anomaly!r}")
    config = MMFConfig.quick() if is_smoke(scale) else PRESET
    seg = config.segmenter
    seg = dataclasses.replace(seg, train=dataclasses.replace(seg.train, seed=SEED_STRIDE * scale.seed))
    frames_scored = scale.anomaly_frames if is_smoke(scale) else ANOMALY_FRAMES
    return MMFDemoConfig(pipeline=dataclasses.replace(config, segmenter=seg), anomaly_split=scale.anomaly_split,
                         anomaly_frames=frames_scored)


def seed_values(scale: Scale, runs: Path, log: Callable) -> tuple[dict, dict, dict]:
    """One seed: ``(values[label], curves[label], info)``; ``info`` has the part keys and timings."""
    config = demo_config(scale)
    pipe_config, seg = config.pipeline, config.pipeline.segmenter
    start = time.perf_counter()
    pipe = MMFPipeline.build(pipe_config, runs / "mmf", progress=False,
                             log=lambda text: log(f"  [{time.perf_counter() - start:.0f} s] {text}"))
    built = time.perf_counter() - start
    predict = predictor(*pipe.segmenter)
    stats = class_statistics(predict, _batches(frames(seg, "train", scale.stats_frames), seg.batch_size))
    miou = segmentation_results(predictions(predict, _batches(frames(seg, "val", scale.val_frames), seg.batch_size)),
                                seg.num_classes)["miou"]
    metrics, curves = anomaly_results(scored_batches(pipe, evaluation_frames(config), pipe_config.batch_size),
                                      [row[1] for row in ROWS], stats=sml.stats_finalize(stats, missing="pooled", policy="none"),
                                      ap_convention="envelope", keep_curves=True)
    keys = {"segmenter": f"segmenter-{pipe_config.part_key('segmenter')}",
            "resynthesis": f"dissimilarity-resynthesis-{pipe_config.part_key('dissimilarity')}",
            "mmf": f"dissimilarity-mmf-{pipe_config.part_key('dissimilarity')}"}
    part = {"resynthesis": "resynthesis", "resynthesis_post": "resynthesis", "mmf_raw": "mmf", "mmf": "mmf"}
    values, thin = {}, {}
    for label, method, _, _ in ROWS:
        m = metrics[method]
        values[label] = {"ap": 100 * m["ap"], "auroc": 100 * m["auroc"], "fpr95": 100 * m["fpr_at_tpr"],
                         "miou": 100 * miou, "network": keys[part.get(method, "segmenter")], "score": method}
        thin[label] = {"roc": _thin(*curves[method]["roc"]), "pr": _thin(*curves[method]["pr"])}
    for label, settings in SLIC_VARIANTS:  # the same networks, the post-processor on other superpixels
        variant = dataclasses.replace(pipe, config=dataclasses.replace(pipe_config, **settings))
        m, c = anomaly_results(scored_batches(variant, evaluation_frames(config), pipe_config.batch_size), ["mmf"],
                               ap_convention="envelope", keep_curves=True)
        values[label] = {"ap": 100 * m["mmf"]["ap"], "auroc": 100 * m["mmf"]["auroc"],
                         "fpr95": 100 * m["mmf"]["fpr_at_tpr"], "miou": 100 * miou, "network": keys["mmf"],
                         "score": "mmf"}
        thin[label] = {"roc": _thin(*c["mmf"]["roc"]), "pr": _thin(*c["mmf"]["pr"])}
    seconds = {"build": built, "total": time.perf_counter() - start}
    log(f"  {NAME} seed {scale.seed}: pipeline built in {built:.0f} s, scored in {seconds['total'] - built:.0f} s")
    return values, thin, {"keys": keys, "seconds": seconds, "config": pipe_config.to_dict()}


def findings(v: dict) -> list[Finding]:
    """Table 2's claims (§IV-C) and Table 1's "MMF is best" on the rows available here."""
    return [
        improves(v, ASSISTED, BASE, ("ap",), "the assistant maps raise the resynthesis net's AP"),
        not_better(v, ASSISTED, BASE, "fpr95", "the assistant maps do not clearly lower FPR95"),
        improves(v, POST, BASE, ("fpr95",), "the post-processor lowers the resynthesis net's FPR95"),
        best(v, FULL, TABLE2, "ap", "both together (MMF) have the best AP of the ablation"),
        best(v, FULL, TABLE2, "fpr95", "both together (MMF) have the best FPR95 of the ablation"),
        improves(v, "entropy", BASE, ("ap",), "Table 1: entropy beats the plain resynthesis net in AP"),
        improves(v, FULL, "entropy", ("ap", "fpr95"), "Table 1: MMF beats softmax entropy in AP and FPR95"),
        best(v, FULL, [row[0] for row in ROWS], "ap", "Table 1: MMF has the best AP of all rows"),
    ]


def run(scale: Scale, seeds: int, out_dir: Path = HERE, runs: Path = RUNS, log: Callable = print,
        description: str = "") -> dict:
    """Every seed, aggregated; writes ``mmf_table2.json/.md/_roc.png/_pr.png``."""
    log(f"{NAME}: {TITLE}")
    scales, values, curves, infos = over_seeds(seed_values, scale, seeds, runs, log)
    config = demo_config(scales[0])
    seg = config.pipeline.segmenter
    # the sizes this table really used (the report states them), seeds as the runner's
    used = [dataclasses.replace(s, height=seg.height, width=seg.width, train_frames=seg.train_frames,
                                steps=seg.train.steps, batch_size=seg.batch_size,
                                anomaly_frames=config.anomaly_frames) for s in scales]
    p = config.pipeline
    minutes = ", ".join(f"{i['seconds']['total'] / 60:.1f}" for i in infos)
    description = (
        f"{description} Sizes: {seg.height} x {seg.width} frames; segmenter {seg.train.steps} steps (the count "
        f"stated below the table) on {seg.train_frames} scenes; RGB-D net ({p.rgbd_backbone}) {p.rgbd_steps} steps; "
        f"two dissimilarity nets (width x {p.dissim_width:g}) {p.dissim_steps} steps each on {p.dissim_frames} "
        f"other scenes with up to {p.void_objects} void clutter objects; SLIC step {p.slic_step or scaled_step((seg.height, seg.width))} px on "
        f"the {p.slic_input}{' with connectivity enforcement' if p.slic_connectivity else ''}; "
        f"{config.anomaly_frames} `{config.anomaly_split}` frames scored in the road ROI. Pipeline seed = "
        f"{SEED_STRIDE} x table seed (no two seeds share a frame set). Minutes per seed in the invocation that "
        f"wrote this table (parts already in the runs folder are restored, not retrained): {minutes}.")
    networks = {k: {"part": part, "mmf_config": i["config"]} for i in infos for part, k in i["keys"].items()}
    steps = (f"training steps: segmenter {seg.train.steps}, RGB-D net {p.rgbd_steps}, dissimilarity nets "
             f"{p.dissim_steps} each")
    return write_table(NAME, TITLE, values, curves, findings, used, networks, out_dir,
                       description.strip(), steps_text=steps)


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
