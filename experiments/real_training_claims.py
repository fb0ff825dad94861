"""The training claims on real frames: CuDAM Table II, the Table III ablation and MSAAM Table 6 on the
CamVid frozen-encoder regime of ``real_training_common`` (the Cityscapes ERFNet's encoder frozen, its
decoder trained on CamVid with a new 11-class head), scored on RoadAnomaly21 and RoadObstacle21.

    python -m experiments.real_training_claims [--networks plain cudam msaam] [--seeds 0 1 2]

Every network is ``real_training_common.train_decoder`` with the baseline's settings (1000 steps,
batch 8, 24x32 feature cells, AdamW 5e-4, ENet class weights) and one change: an attention module at
ERFNet's ``deep`` position (the encoder's output, the position CuDAM's Table V finds best; MSAAM's
"end of the encoder") trained with its paper's objective: CuDAM's Eq. 8 with the paper-equivalent
tau (5e4 rescaled to the crop's 24 x 32 map), MSAAM's Eq. 7. A row differs from the baseline by the
module alone, and networks of one seed share the head's initialisation and the batches.

Per network and seed (cached beside the run, ``claims-<version>.npz``): per-frame confusion matrices
of the 233 CamVid test frames (mIoU); SML statistics (Eqs. 3-4, the original estimate) from the 367
CamVid training frames; every score of each anomaly frame, the frame resized (area) to CamVid's 480
columns, the network run on it, each score map resized back bilinearly to the label's size and its
non-void pixels kept. CuDAM's ensemble (Eq. 10) adds ``sigma * up(M_att)`` with sigma = 2e4 rescaled
to the test map's positions (``paper_sigma``).

Findings are decided as the synthetic tables' (``experiments.common``): a paired hierarchical
bootstrap over seeds and frames (anomaly frames for AP / FPR95 / AUROC, CamVid test frames for
mIoU), a finding holding where the 95% interval of the paired difference excludes 0 in the paper's
direction; tested only where every network of its rows reaches ``COMPETENT`` (55%) CamVid test mIoU.
Positive controls: Eq. 10 with an attention map on the anomalies (``oracle_attention``) must beat SML
of the same CuDAM network; with the logits scaled per predicted class (1/4 to 4), SML (fitted on the
scaled training logits) must beat max logit.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from experiments import common
from experiments.common import (LOGIT_SCALE_CONTROL, ORACLE_BASE, ORACLE_CONTROL, Finding, aggregate, best, improves,
                                markdown, ordered, paired_replicates, score_histograms)
from experiments.real_common import HERE, anomaly_tracks, resized
from experiments.real_training_baseline import COMPETENT
from experiments.real_training_common import (CACHE, CACHE_VERSION, Settings, cache_features, cache_taps,
                                              cityscapes_erfnet, decoder_outputs, encoder_module,
                                              encoder_variables, run_folder, settings_key, train_decoder)

NAME = "real_training_claims"
EVALUATION_VERSION = 1  # bump when what an evaluation holds changes
WIDTH = 480  # anomaly frames are resized to CamVid's width
# name -> the Settings fields that differ from the baseline's
NETWORKS = {
    "plain": {},
    "cudam": {"attention": "cudam"},
    "msaam": {"attention": "msaam"},
    "cudam_attention_only": {"attention": "cudam", "objective": (("beta", 0.0), ("reward_prob", 0.0))},
    "cudam_reward": {"attention": "cudam", "objective": (("beta", 0.0),)},
}
BASE = ("msp", "max_logit", "entropy", "sml_post")
ENSEMBLE = ("msp", "max_logit", "sml_post")  # scored again with the network's attention (Eq. 10)

# (row label, network, score); a row is shown where its network has been trained for every seed
ROWS = [
    ("MSP", "plain", "msp"), ("max logit", "plain", "max_logit"), ("entropy", "plain", "entropy"),
    ("SML", "plain", "sml_post"),
    ("CuDAM + MSP", "cudam", "msp+att"), ("CuDAM + max logit", "cudam", "max_logit+att"),
    ("CuDAM + SML", "cudam", "sml_post+att"), ("CuDAM network, SML without attention term", "cudam", "sml_post"),
    ("attention", "cudam_attention_only", "sml_post+att"), ("attention + reward", "cudam_reward", "sml_post+att"),
    ("MSAAM + MSP", "msaam", "msp"), ("MSAAM + max logit", "msaam", "max_logit"),
    ("MSAAM + entropy", "msaam", "entropy"), ("MSAAM + SML", "msaam", "sml_post"),
    (ORACLE_CONTROL, "cudam", "sml_post+oracle"), (ORACLE_BASE, "cudam", "sml_post"),
    (LOGIT_SCALE_CONTROL + "max logit", "plain", "scaled_max_logit"),
    (LOGIT_SCALE_CONTROL + "SML", "plain", "scaled_sml"),
]


def settings(network: str, seed: int, steps: int = Settings.steps) -> Settings:
    return Settings(seed=seed, steps=steps, **NETWORKS[network])


# ----------------------------------------------------------------------------- the anomaly frames
def anomaly_frames(track: str, root: Path, log=print) -> list[dict]:
    """Each frame of a track as the frozen encoder sees it at ``WIDTH`` columns: ``{"features", "low",
    "mid"}`` (batch of one) and its full-size ``label``; cached under ``CACHE`` (keyed by the weights,
    the track's frame names and the width)."""
    import jax

    from jaxanom.data.smiyc import SegmentMeIfYouCan
    from jaxanom.io import write_bytes_atomic
    from jaxanom.models.erfnet import normalize_erfnet

    frames = SegmentMeIfYouCan(root)
    _, _, weights = cityscapes_erfnet()
    names = [frames[i]["name"] for i in range(len(frames))]
    key = settings_key({"weights": weights, "frames": names, "width": WIDTH, "version": CACHE_VERSION})
    path = CACHE / f"anomaly-{track}-{key}.npz"
    if not path.exists():
        encoder, variables = encoder_module(with_taps=True), encoder_variables()
        forward = jax.jit(lambda v, x: encoder.apply(v, normalize_erfnet(x), train=False))
        arrays = {}
        for i in range(len(frames)):
            frame = frames[i]
            features, taps = forward(variables, resized(frame["image"], WIDTH)[None])
            arrays.update({f"{i}/features": features, f"{i}/low": taps["low"], f"{i}/mid": taps["mid"],
                           f"{i}/label": frame["label"]})
            log(f"  encoded {track} {i + 1}/{len(frames)}")
        import io

        buffer = io.BytesIO()
        np.savez(buffer, **{k: np.asarray(v) for k, v in arrays.items()})
        write_bytes_atomic(path, buffer.getvalue())
    with np.load(path) as stored:
        return [{k: stored[f"{i}/{k}"] for k in ("features", "low", "mid", "label")} for i in range(len(frames))]


# ----------------------------------------------------------------------------- one network's evaluation
def class_factors(num_classes: int) -> np.ndarray:
    return np.asarray(common.control_scales(num_classes), np.float32)


def scaled(logits: np.ndarray) -> np.ndarray:
    """The logit-scale control's logits: each pixel's multiplied by its predicted class's factor."""
    factors = class_factors(logits.shape[-1])
    return logits * factors[np.argmax(logits, -1)][..., None]


def frame_scores(out: dict, stats, scaled_stats, label: np.ndarray) -> dict[str, np.ndarray]:
    """Every score (``BASE``, the controls', with attention ``<base>+att`` and the oracle's) of one frame's
    outputs (batch of one), resized to ``label``'s (H, W), float32."""
    import cv2

    from jaxanom.app.scoring import inputs_of, score_all
    from jaxanom.cudam.score import cudam_score, paper_sigma, upsample_attention

    logits = np.asarray(out["logits"], np.float32)
    scores, _ = score_all(BASE, inputs_of({"logits": logits}, stats))
    control, _ = score_all(("max_logit", "sml"), inputs_of({"logits": scaled(logits)}, scaled_stats))
    scores.update({f"scaled_{name}": value for name, value in control.items()})
    sigma = None
    if "attention" in out:
        attention = np.asarray(out["attention"], np.float32)
        positions = attention.shape[-2] * attention.shape[-1]
        sigma = paper_sigma(positions)
        attention_up = upsample_attention(attention, logits.shape[1:3])
        for name in ENSEMBLE:
            scores[f"{name}+att"] = cudam_score(scores[name], attention_up, sigma)
    full = {name: cv2.resize(np.asarray(value[0], np.float32), label.shape[::-1], interpolation=cv2.INTER_LINEAR)
            for name, value in scores.items()}
    if sigma is not None:
        oracle = common.oracle_attention(label[None], positions)[0]
        full["sml_post+oracle"] = np.asarray(cudam_score(full["sml_post"], oracle, sigma))
    return full


def evaluate(network: str, seed: int, steps: int = Settings.steps, log=print) -> dict:
    """One trained network's evaluation (module docstring): ``{"confusion": (233, C, C), "miou",
    "<track>/sizes": (F,) non-void pixels per frame, "<track>/labels": their uint8 labels, "<track>/<score>":
    their float32 scores}`` (frames concatenated: ``per_frame``); trained first where missing, cached
    beside the run."""
    import jax

    from jaxanom import sml
    from jaxanom.metrics import miou
    from jaxanom.metrics.evaluator import Segmentation

    s = settings(network, seed, steps)
    folder = train_decoder(s, log)
    path = folder / f"claims-{EVALUATION_VERSION}.npz"
    if path.exists():
        with np.load(path) as stored:
            return {k: stored[k] for k in stored.files}
    start = time.perf_counter()
    variables = jax.device_get(train_variables(folder, s))

    def taps(split: str):
        return cache_taps(split, False, log) if s.attention is not None else None

    features, labels, _ = cache_features("test", False, log)
    confusion = np.concatenate([Segmentation(s.num_classes).frame_states({"logits": out["logits"],
                                                                           "label": labels[i:i + 4]})
                                for i, out in zip(range(0, len(features), 4),
                                                  decoder_outputs(variables, s, features, taps("test")))])
    features, _, _ = cache_features("train", False, log)
    stats = scaled_stats = sml.stats_init(s.num_classes)
    for out in decoder_outputs(variables, s, features, taps("train")):
        logits = np.asarray(out["logits"])
        stats, scaled_stats = sml.stats_update_batch(stats, logits), sml.stats_update_batch(scaled_stats, scaled(logits))
    del features
    finalized = [sml.stats_finalize(x, missing="pooled", policy="none") for x in (stats, scaled_stats)]
    arrays = {"confusion": confusion, "miou": np.float64(miou(confusion.sum(0)))}
    for track, root in anomaly_tracks().items():
        per_score, kept_labels = {}, []
        for frame in anomaly_frames(track, root, log):
            extras = {"low": frame["low"], "mid": frame["mid"]} if s.attention is not None else None
            out = next(decoder_outputs(variables, s, frame["features"], extras))
            keep = frame["label"] != 255
            kept_labels.append(frame["label"][keep].astype(np.uint8))
            for name, value in frame_scores(out, *finalized, frame["label"]).items():
                per_score.setdefault(name, []).append(value[keep])
        arrays[f"{track}/sizes"] = np.array([len(x) for x in kept_labels])
        arrays[f"{track}/labels"] = np.concatenate(kept_labels)
        for name, values in per_score.items():
            arrays[f"{track}/{name}"] = np.concatenate(values)
    partial = folder / f"claims-{EVALUATION_VERSION}.partial.npz"
    np.savez(partial, **arrays)
    partial.replace(path)
    log(f"{network} seed {seed}: test mIoU {100 * arrays['miou']:.2f}, evaluated in {time.perf_counter() - start:.0f} s")
    return arrays


def per_frame(evaluation: dict, track: str, key: str) -> list[np.ndarray]:
    """One track's ``key`` (``"labels"`` or a score) of an evaluation, split into its frames."""
    return np.split(evaluation[f"{track}/{key}"], np.cumsum(evaluation[f"{track}/sizes"])[:-1])


def train_variables(folder: Path, s: Settings) -> dict:
    """The trained decoder's (and attention module's) variables: the run's, without the encoder."""
    from jaxanom.app.experiment import load_variables

    _, stored = load_variables(folder / "run")
    return {collection: {k: v for k, v in tree.items() if k != "encoder"} for collection, tree in stored.items()}


# ----------------------------------------------------------------------------- tables and findings
def exact(scores: list[np.ndarray], labels: list[np.ndarray]) -> dict[str, float]:
    """Percent AP, AUROC and FPR95 of the pooled frames, exactly (``PixelAnomaly``)."""
    from jaxanom.metrics.evaluator import PixelAnomaly, run_evaluators

    frames = ({"scores": {"s": s}, "label": l} for s, l in zip(scores, labels))
    m = run_evaluators({"p": PixelAnomaly("s")}, frames)["p"]
    return {"ap": 100 * m["ap"], "auroc": 100 * m["auroc"], "fpr95": 100 * m["fpr_at_tpr"]}


def evaluation_path(network: str, seed: int) -> Path:
    return run_folder(settings(network, seed)) / f"claims-{EVALUATION_VERSION}.npz"


def row_scores(network: str) -> tuple[str, ...]:
    """The scores of ``network`` that rows of ``ROWS`` read."""
    return tuple(dict.fromkeys(score for _, n, score in ROWS if n == network))


def summary(network: str, seed: int, log=print) -> dict:
    """What the tables read of one evaluation, per track and row score: ``<track>/<score>/exact`` (percent
    AP, AUROC, FPR95, exactly), ``.../binned`` (the same of all frames' histograms) and ``.../histograms``
    (per-frame, ``score_histograms``); with ``confusion`` and ``miou``. Cached beside the evaluation:
    the exact metrics of 19M pooled pixels take tens of seconds each."""
    path = evaluation_path(network, seed).with_name(f"claims-{EVALUATION_VERSION}-summary.npz")
    if not path.exists():
        start = time.perf_counter()
        e = evaluate(network, seed, log=log)
        out = {"confusion": e["confusion"], "miou": e["miou"]}
        for track in anomaly_tracks():
            labels = per_frame(e, track, "labels")
            for score in row_scores(network):
                scores = per_frame(e, track, score)
                metrics = exact(scores, labels)
                out[f"{track}/{score}/histograms"], binned = score_histograms(scores, labels)
                out[f"{track}/{score}/exact"] = np.array([metrics[k] for k in METRICS])
                out[f"{track}/{score}/binned"] = np.array([binned[k] for k in METRICS])
        partial = path.with_name(path.name.replace(".npz", ".partial.npz"))
        np.savez(partial, **out)
        partial.replace(path)
        log(f"{network} seed {seed}: summarised in {time.perf_counter() - start:.0f} s")
    with np.load(path) as stored:
        return {k: stored[k] for k in stored.files}


METRICS = ("ap", "auroc", "fpr95")


def track_values(track: str, summaries: dict[str, list[dict]], rows) -> dict:
    """The rows of one track over the seeds (``summaries[network][i]``: seed i's ``summary``):
    ``aggregate`` of each seed's exact metrics and test mIoU, with the paired hierarchical
    bootstrap's replicates."""
    per_seed, per_seed_frames = [], []
    for s in range(len(summaries["plain"])):
        values, frames = {}, {}
        for label, network, score in rows:
            e = summaries[network][s]
            exact_values = dict(zip(METRICS, e[f"{track}/{score}/exact"].tolist()))
            binned = dict(zip(METRICS, e[f"{track}/{score}/binned"].tolist()))
            values[label] = {**exact_values, "miou": 100 * float(e["miou"]), "network": network, "score": score,
                             "competent_miou": COMPETENT,
                             "binning": max(abs(binned[k] - exact_values[k]) for k in METRICS)}
            frames[label] = {"histograms": e[f"{track}/{score}/histograms"], "confusion": e["confusion"]}
        per_seed.append(values)
        per_seed_frames.append(frames)
    values = aggregate(per_seed)
    for label, replicates in paired_replicates(per_seed_frames).items():
        values[label]["replicates"] = replicates
    return values


def findings(v: dict) -> dict[str, list[Finding]]:
    """The papers' findings that ``v``'s rows can test, by table."""
    have = set(v)
    table2, table3, table6 = [], [], []
    three = ("ap", "fpr95", "auroc")
    if {"CuDAM + SML", "SML"} <= have:
        table2 += [improves(v, f"CuDAM + {s}", s, three, f"CuDAM improves {s} in AP, FPR95 and AUROC")
                   for s in ("MSP", "max logit", "SML")]
        table2 += [ordered(v, ["MSP", "max logit", "SML"], "ap", "without CuDAM, AP: MSP < max logit < SML"),
                   ordered(v, ["CuDAM + MSP", "CuDAM + max logit", "CuDAM + SML"], "ap",
                           "with CuDAM, AP: MSP < max logit < SML"),
                   improves(v, "CuDAM + SML", "SML", ("miou",), "CuDAM raises mIoU slightly")]
    ablations = [a for a in ("attention", "attention + reward") if a in have]
    if ablations and "CuDAM + SML" in have:
        full = "CuDAM + SML"
        table3 += [improves(v, a, "SML", ("ap",), f"{a} improves AP over no CuDAM") for a in ablations]
        table3 += [best(v, full, ["SML", *ablations, full], m, f"all three components give the best {m.upper()}")
                   for m in ("ap", "fpr95")]
    if "MSAAM + SML" in have:
        table6 = [improves(v, f"MSAAM + {s}", s, three, f"MSAAM improves {s} in AP, FPR95 and AUROC")
                  for s in ("MSP", "max logit", "entropy", "SML")]
    return {"CuDAM Table II": table2, "CuDAM Table III (attention + L_att not trained)": table3,
            "MSAAM Table 6": table6}


def controls(v: dict) -> list[Finding]:
    out = [common.logit_scale_control(v)]
    if ORACLE_CONTROL in v:
        out.append(common.oracle_control(v))
    return out


def mious(v: dict) -> str:
    """Each network's CamVid test mIoU against the baseline's, with the paired interval."""
    first = {}
    for label, row in v.items():
        first.setdefault(row["network"], label)
    lines = []
    for network, label in first.items():
        text = f"`{network}` {row_cell(v[label], 'miou')}"
        if network != "plain":
            c = common.comparison(v, label, first["plain"], "miou")
            text += f" (Δ {c['difference']:+.2f} [{c['low']:+.2f}, {c['high']:+.2f}] against `plain`)"
        lines.append(text)
    return "; ".join(lines)


def row_cell(row: dict, metric: str) -> str:
    return f"{row[metric]:.2f} ± {row[metric + '_std']:.2f}" if row.get(metric + "_std") else f"{row[metric]:.2f}"


def finding_lines(found: list[Finding]) -> list[str]:
    lines = ["| paper's finding | holds here? | tested? | evidence |", "|---|---|---|---|"]
    for f in found:
        tested = "n/a" if f.tested is None else "yes" if f.tested else f"**no**: {f.untested_because}"
        lines.append(f"| {f.claim} | {'yes' if f.holds else '**no**'} | {tested} | {f.evidence} |")
    return lines


# the tables: each compares the baseline with the networks of one paper, on the seeds all of them have
GROUPS = {"CuDAM": ("cudam", "cudam_attention_only", "cudam_reward"), "MSAAM": ("msaam",)}


def group_tables(seeds: list[int], log=print) -> dict:
    """``{group: {"seeds", "networks", "not_trained", "tracks": {track: values}}}`` from the evaluations
    that exist (nothing is trained): a group's seeds are those where the baseline and its first network
    are evaluated; its other networks join where evaluated for all of them."""
    tables = {}
    for group, networks in GROUPS.items():
        have = [s for s in seeds if all(evaluation_path(n, s).exists() for n in ("plain", networks[0]))]
        if not have:
            continue
        present = ["plain", *[n for n in networks if all(evaluation_path(n, s).exists() for s in have)]]
        summaries = {n: [summary(n, s, log) for s in have] for n in present}
        rows = [row for row in ROWS if row[1] in present]
        tables[group] = {"seeds": have, "networks": present, "not_trained": [n for n in networks if n not in present],
                         "tracks": {track: track_values(track, summaries, rows) for track in anomaly_tracks()}}
    return tables


def report(tables: dict) -> str:
    lines = ["# Training claims on real frames: CuDAM and MSAAM on the CamVid regime", "",
             f"Written by `python -m experiments.{NAME}` (the method: its docstring and docs/decisions/camvid.md). "
             "Every network: 1000 decoder steps (batch 8, 24x32 feature cells) on the frozen Cityscapes ERFNet "
             "encoder, the baseline's settings plus one attention module with its paper's objective. Values are "
             "means ± sample std over seeds; the evidence gives the paired difference and its 95% interval "
             "(hierarchical bootstrap, 1000 replicates, over seeds and, inside each, frames). A finding is tested "
             f"only where every network of its rows reaches {COMPETENT:g}% CamVid test mIoU. Anomaly metrics are "
             "pooled over each track's non-void pixels at the labels' size (exact); intervals from per-frame "
             f"histograms over {common.TABLE_BINS} bins.", ""]
    for group, table in tables.items():
        lines += [f"## {group}: networks {', '.join(f'`{n}`' for n in table['networks'])}; seeds "
                  f"{', '.join(map(str, table['seeds']))}", "",
                  "Not trained yet (rows and findings left out): "
                  f"{', '.join(f'`{n}`' for n in table['not_trained']) or 'none'}.", ""]
        for track, v in table["tracks"].items():
            binning = max(row["binning"] for row in v.values())
            lines += [f"### {track}", "", markdown([{"label": k, **row} for k, row in v.items()]), "",
                      f"CamVid test mIoU: {mious(v)}. Binned metrics within {binning:.2f} points of the exact ones.",
                      ""]
            for name, found in findings(v).items():
                if found:
                    lines += [f"{name}:", "", *finding_lines(found), ""]
            lines += ["Positive controls (built so that the mechanism must help; a failing one points at a bug):",
                      "", *finding_lines(controls(v)), ""]
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--networks", nargs="+", default=list(NETWORKS), choices=list(NETWORKS),
                        help="the networks to train and evaluate where missing (default: all)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--train-only", action="store_true", help="train, evaluate and summarise; write no tables")
    parser.add_argument("--tables-only", action="store_true",
                        help="train nothing: the tables of the networks already evaluated")
    args = parser.parse_args(argv)
    if not args.tables_only:
        for network in ["plain", *[n for n in args.networks if n != "plain"]]:
            for seed in args.seeds:
                summary(network, seed)
    if args.train_only:
        return
    tables = group_tables(args.seeds)
    out = {"competent_miou": COMPETENT,
           "groups": {group: {**{k: table[k] for k in ("seeds", "networks", "not_trained")},
                              "tracks": {track: {"table": [common._row_json(k, row) for k, row in v.items()],
                                                 "findings": {t: [dataclasses.asdict(f) for f in found]
                                                              for t, found in findings(v).items()},
                                                 "controls": [dataclasses.asdict(f) for f in controls(v)]}
                                         for track, v in table["tracks"].items()}}
                      for group, table in tables.items()}}
    (HERE / f"{NAME}.json").write_text(json.dumps(out, indent=1) + "\n")
    (HERE / f"{NAME}.md").write_text(report(tables) + "\n")
    print((HERE / f"{NAME}.md").read_text())


if __name__ == "__main__":
    main()
