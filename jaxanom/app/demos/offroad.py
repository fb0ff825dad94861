"""``jaxanom demo offroad``: the three stages of the off-road paper on synthetic sequences.

S1 learns from patch-annotated frames of domain A; S2 measures the frame-level risk on a
sequence of the shifted domain B (active learning) and on the test sequence C; S3 runs one
active-learning round on B (hard frames by Eq. 16, simulated annotations, fine-tuning, refit);
then mFLR / scene coverage on B and C, pixel accuracy and mIoU on C (LV3 classes through the
cluster -> class map, unknown counted wrong) with and without the CRF are compared before and
after the round. Writes ``results.json``, ``frame_<i>_{before,after}.png`` (frame | ground truth | window
labels | voted labels | risk map | CRF labels, titled, with a class legend and a colour bar) and
``hard_frames.png`` (the frames chosen by Eq. 16 with their frame risk).
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from jaxanom.app.offroad_experiment import (OffroadDemoConfig, annotated, as_float, class_names, num_classes,
                                            source_frames)
from jaxanom.app.offroad_pipeline import (OffroadModel, active_round, learn, segment, segmentation_scores,
                                          sequence_risk_sweep, to_classes)
from jaxanom.config_codec import encode
from jaxanom.io import write_json_atomic
from jaxanom.offroad.risk import mean_frame_risk, scene_coverage

_PALETTE = [(140, 100, 60), (160, 160, 160), (230, 150, 40), (235, 235, 210), (110, 210, 70), (40, 130, 50),
            (0, 80, 0), (120, 120, 255), (170, 60, 20), (130, 190, 255)]


def _palette(count: int) -> list[tuple[int, int, int]]:
    """The LV3-like palette, cycled beyond 10 classes."""
    return [_PALETTE[i % len(_PALETTE)] for i in range(count)]


def _window_labels(seg: dict, index: int, model: OffroadModel, classes: int, shape, stride: int) -> np.ndarray:
    """Each window's class painted as a stride x stride square at its centre (255 elsewhere)."""
    panel = np.full(shape, 255, np.int64)
    labels = to_classes(seg["window_labels"][index], model, classes)
    for (r, c), label in zip(seg["centers"], labels):
        panel[max(r - stride // 2, 0):r + (stride + 1) // 2, max(c - stride // 2, 0):c + (stride + 1) // 2] = label
    return panel


def _evaluate(model: OffroadModel, test: list[dict], config: OffroadDemoConfig, progress) -> tuple[dict, dict]:
    pipe, classes = config.pipeline, num_classes(config)
    images = as_float(test)
    flr = sequence_risk_sweep(model, images, pipe, progress=progress)
    picked = np.linspace(0, len(test) - 1, config.segmented).round().astype(int)
    seg = segment(model, images[picked], pipe, crf=True)
    truth = np.stack([test[i]["label"] for i in picked])
    scores = {"mflr": mean_frame_risk(flr), "coverage": scene_coverage(flr, pipe.epsilon), "clusters": model.num_clusters}
    for name, labels in (("votes", seg["labels"]), ("crf", seg["crf_labels"])):
        s = segmentation_scores(to_classes(labels, model, classes), truth, classes)
        scores[name] = {"pixel_accuracy": s["pixel_accuracy"], "miou": s["miou"]}
    return scores, {"flr": flr, "segments": seg, "picked": picked}


def _write_pictures(out_dir: Path, tag: str, model: OffroadModel, test: list[dict], detail: dict,
                    config: OffroadDemoConfig) -> None:
    from jaxanom.viz import Panel, label_panel, write_panels

    names = class_names(config)
    classes, palette = len(names), _palette(len(names))
    seg = detail["segments"]

    def labels(title, ids, void=("void", (255, 255, 255))):  # ids in [0, classes], classes = unknown
        return label_panel(title, ids, names + ("unknown",), palette + [(0, 0, 0)], void=void)

    for j in range(min(config.pictures, len(detail["picked"]))):
        frame = test[detail["picked"][j]]
        windows = _window_labels(seg, j, model, classes, frame["label"].shape, config.pipeline.stride)
        panels = [Panel(f"test frame {detail['picked'][j]} ({tag} the round)", frame["image"]),
                  labels("ground truth", frame["label"]),
                  labels("window labels (S2)", windows, void=("no window", (255, 255, 255))),
                  labels("voted labels", to_classes(seg["labels"][j], model, classes)),
                  Panel("risk map", seg["risk"][j], vmin=0.0, vmax=1.0, label="risk"),
                  labels("CRF labels", to_classes(seg["crf_labels"][j], model, classes))]
        write_panels(out_dir / f"frame_{j}_{tag}.png", panels)


def _write_hard_frames(out_dir: Path, active: list[dict], chosen: list[int], flr: np.ndarray) -> None:
    from jaxanom.viz import Panel, write_panels

    write_panels(out_dir / "hard_frames.png",
                 [Panel(f"frame {i}: frame risk {float(flr[i]):.3f}", active[i]["image"]) for i in chosen], columns=4)


def run_offroad_demo(out_dir: str | Path, config: OffroadDemoConfig = OffroadDemoConfig(), *, progress: bool = True,
                     log=print) -> dict:
    """Run the demo into ``out_dir``; returns the results (also written to ``results.json``)."""
    from tqdm.auto import tqdm

    out_dir, started = Path(out_dir), time.perf_counter()
    bar = lambda desc: (lambda it: tqdm(it, desc=desc, disable=not progress, dynamic_ncols=True, leave=False))  # noqa: E731
    pipe = config.pipeline
    key = jax.random.key(config.seed)
    train = [f for source in config.train for f in source_frames(source, config)]
    data = annotated(train, config, 0)
    log(f"[1/4] S1: encoder on {len(train)} patch-annotated frames of domain {config.train[0].domain} "
        f"({int(data.valid.sum())} patches, {pipe.encoder.steps} steps), GMM by BIC over m in "
        f"{pipe.components[0]}..{pipe.components[-1]}")
    model = learn(jax.random.fold_in(key, 1), data, pipe, progress=bar("encoder"))
    chosen_m = model.num_clusters
    log(f"      BIC-chosen cluster count: {chosen_m}; r_sigma = {model.r_sigma:.3f}")

    active = source_frames(config.active, config)
    test = source_frames(config.test, config)
    log(f"[2/4] S2: risk on the active-learning sequence ({len(active)} frames of {config.active.domain}) "
        f"and the test sequence ({len(test)} frames of {config.test.domain})")
    before, before_detail = _evaluate(model, test, config, bar("test risk"))
    _write_pictures(out_dir, "before", model, test, before_detail, config)

    log(f"[3/4] S3: active learning round (budget {pipe.budget}, gap {pipe.gap})")

    def annotate_frames(indices):
        return annotated([active[i] for i in indices], config, 1)

    round_ = active_round(jax.random.fold_in(key, 2), model, data, as_float(active), annotate_frames, pipe,
                          force=True, progress=bar("active"))
    after_model = round_["model"]
    chosen = round_["chosen"].tolist()
    _write_hard_frames(out_dir, active, chosen, round_["flr"])
    flr_active_after = sequence_risk_sweep(after_model, as_float(active), pipe, progress=bar("active risk"))

    log("[4/4] evaluating after the round")
    after, after_detail = _evaluate(after_model, test, config, bar("test risk"))
    _write_pictures(out_dir, "after", after_model, test, after_detail, config)
    results = {
        "clusters_bic": chosen_m, "bics": {str(k): v for k, v in model.bics.items()},
        "clusters_after": after_model.num_clusters,
        "active_sequence": {"mflr_before": mean_frame_risk(round_["flr"]), "coverage_before": scene_coverage(round_["flr"], pipe.epsilon),
                            "sequence_risk_before": round_["sequence_risk"], "triggered": round_["sequence_risk"] > pipe.trigger,
                            "mflr_after": mean_frame_risk(flr_active_after),
                            "coverage_after": scene_coverage(flr_active_after, pipe.epsilon), "hard_frames": chosen},
        "test_before": before, "test_after": after, "seconds": time.perf_counter() - started,
        "config": encode(config),
    }
    write_json_atomic(out_dir / "results.json", results)
    log(results_table(results))
    log(f"results in {out_dir}/ (results.json, frame_*_before.png, frame_*_after.png, hard_frames.png); "
        f"{results['seconds']:.0f} s")
    return results


def results_table(results: dict) -> str:
    """A markdown table of mFLR / coverage / PA / mIoU before and after the active-learning round."""
    a = results["active_sequence"]
    lines = [f"BIC-chosen clusters: {results['clusters_bic']} (after the round: {results['clusters_after']}); "
             f"hard frames: {a['hard_frames']}",
             "| model | mFLR B | Sc B | mFLR C | Sc C | PA C | mIoU C | PA C + CRF | mIoU C + CRF |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, tag, m, s in (("before", "test_before", a["mflr_before"], a["coverage_before"]),
                            ("after one round", "test_after", a["mflr_after"], a["coverage_after"])):
        t = results[tag]
        lines.append(f"| {name} | {100 * m:.1f} | {100 * s:.1f} | {100 * t['mflr']:.1f} | {100 * t['coverage']:.1f} | "
                     f"{100 * t['votes']['pixel_accuracy']:.1f} | {100 * t['votes']['miou']:.1f} | "
                     f"{100 * t['crf']['pixel_accuracy']:.1f} | {100 * t['crf']['miou']:.1f} |")
    return "\n".join(lines)
