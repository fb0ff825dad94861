"""MMF's post-processor (Eq. 6 over SLIC superpixels) on real uncertainty maps of two networks: the
ESPNet and ERFNet authors' Cityscapes weights (``real_common.NETWORKS``) on RoadObstacle21 (scored in
its road region) and RoadAnomaly21;
entropy (Eq. 1) and softmax distance (Eq. 2), each alone and through Eq. 6 with three SLIC
segmentations; envelope AP (Eq. 7) and FPR95 with 95% bootstrap intervals over frames, paired
for the findings and across the networks (the same frame draws for every row of both); the
per-frame time of SLIC + Eq. 6 at the native size.

    python -m experiments.real_mmf_post [--tracks RoadAnomaly21]   # writes real_mmf_post.json / .md beside this file

Both networks run at once, each in its own process. ``--tracks RoadAnomaly21`` took 19.1 min wall on
2 CPU cores shared with ~25 other processes; RoadObstacle21 scores about twice its pixels (19.2M
against 8.9M) in three times the frames.

Set-up:
* Network input as ``real_sml`` (each frame resized to 1024 wide, both networks' training scale;
  ESPNet's 20 channels, ERFNet's 19 trainIds); the maps of ``mmf.uncertainty`` (entropy normalised
  by log2 C, softmax distance, road probability = softmax channel 0) are resized bilinearly to the
  frame's native size (1080x1920, 720x1280).
* Eq. 6 (``mmf.postprocess.superpixel_score_batch``, road probability p_j from the same network)
  at the native size over SLIC superpixels from ``mmf.training_free.segment`` with the scaled
  step (``superpixels.scaled_step``: S = 32, K = 2040 at 1080x1920; S = 21, K = 2074 at
  720x1280), compactness 10, 10 iterations: "RGB SLIC" on the frame's Lab image; "connected" the
  same with connectivity enforced; "SLIC on the map" on the uncertainty map itself (one channel,
  scaled to [0, 100]: the paper's reading of Sec. III-B / Fig. 4).
* Max logit (``scores.max_logit``) at the same resolution as a baseline row.
* Metrics pooled over the non-void pixels (RoadObstacle21: the road region). A finding "holds"
  when the paired 95% interval of the difference lies beyond 0 in the paper's direction;
  "contradicted" when it lies beyond 0 the other way.
"""
from __future__ import annotations

import functools
import time

import cv2
import numpy as np

from experiments.real_common import (HERE, NETWORKS, logits_of, per_network, resized, same_frames, selected_tracks,
                                     with_intervals)
from experiments.real_sml import STRONGER, WEAKER, WIDTH, arguments
from experiments.stats import REPLICATES, difference, difference_change, draws, network_difference
from jaxanom import scores as S
from jaxanom.data.smiyc import SegmentMeIfYouCan
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.mmf.postprocess import superpixel_score_batch
from jaxanom.mmf.training_free import segment
from jaxanom.mmf.uncertainty import uncertainty_maps

NAME = "real_mmf_post"
BASES = {"entropy": "entropy", "softmax distance": "distance"}  # row name: key of uncertainty_maps
VARIANTS = (" + Eq. 6 (RGB SLIC)", " + Eq. 6 (connected)", " + Eq. 6 (SLIC on the map)")
ROWS = ("max logit", *(base + suffix for base in BASES for suffix in ("", *VARIANTS)))
TIMES = ("slic_rgb", "slic_connected", "slic_map (both maps)", "eq6 (one map)", "slic_rgb + eq6 (one map)")


def upsampled(x: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) float map -> (H, W) float32, bilinear (as ``real_sml``)."""
    return cv2.resize(np.asarray(x, np.float32), shape[::-1], interpolation=cv2.INTER_LINEAR)


def timed(fn, *args, **kwargs):
    """(result as NumPy, seconds) of a blocking call."""
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    if isinstance(out, dict):  # labels as NumPy, the segment count kept an int
        out = {k: np.asarray(v) if hasattr(v, "shape") else v for k, v in out.items()}
    else:
        out = np.asarray(out)
    return out, time.perf_counter() - start


def frame_maps(logits: np.ndarray, image: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Every row's map at the image's (H, W) and the seconds of each SLIC and of Eq. 6."""
    shape = image.shape[:2]
    network = uncertainty_maps(logits)
    road = upsampled(network["road"], shape)[None]
    maps = {"max logit": upsampled(S.max_logit(logits), shape)}
    bases = {name: upsampled(network[key], shape) for name, key in BASES.items()}
    segs, seconds = {}, {}
    segs["RGB SLIC"], seconds["slic_rgb"] = timed(segment, image[None], {})
    segs["connected"], seconds["slic_connected"] = timed(segment, image[None], {}, connectivity=True)
    on_map, seconds["slic_map (both maps)"] = timed(segment, image[None], {k: v[None] for k, v in bases.items()},
                                                   slic_input="anomaly")
    eq6 = 0.0
    for name, value in bases.items():
        maps[name] = value
        for variant, labels in zip(VARIANTS, (segs["RGB SLIC"]["superpixels"], segs["connected"]["superpixels"],
                                              on_map[name])):
            score, spent = timed(superpixel_score_batch, value[None], road, labels, on_map["num_segments"])
            maps[name + variant] = score[0]
            eq6 += spent
    seconds["eq6 (one map)"] = eq6 / (len(BASES) * len(VARIANTS))
    seconds["slic_rgb + eq6 (one map)"] = seconds["slic_rgb"] + seconds["eq6 (one map)"]
    return maps, seconds


def track_scores(predict, root, log=print):
    """Non-void pixels of every row's map per frame, the labels, and per-frame timings."""
    frames = SegmentMeIfYouCan(root)
    scores, labels, times = {}, [], []
    for i in range(len(frames)):
        frame = frames[i]
        keep = frame["label"] != 255
        labels.append(frame["label"][keep])
        maps, seconds = frame_maps(logits_of(predict, resized(frame["image"], WIDTH)), frame["image"])
        for name, value in maps.items():
            scores.setdefault(name, []).append(value[keep])
        times.append(seconds)
        log(f"  {root.name} {i + 1}/{len(frames)} {frame['name']} "
            + ", ".join(f"{k} {v:.2f} s" for k, v in seconds.items()))
    return scores, labels, times


def findings(replicates: dict) -> list[dict]:
    """Per base map and SLIC variant: Eq. 6 lowers FPR95 (the paper's main claim) and raises the
    envelope AP (its smaller claim); paired intervals."""
    out = []
    for base in BASES:
        for variant in VARIANTS:
            a = base + variant
            ap, fpr = difference(replicates, a, base, "ap_envelope"), difference(replicates, a, base, "fpr_at_tpr")
            for text, pair, sign in ((f"Eq. 6 lowers FPR95 of {base} ({variant[10:-1]})", fpr, -1),
                                     (f"Eq. 6 raises AP of {base} ({variant[10:-1]})", ap, 1)):
                verdict = ("held" if (pair[1] < 0 if sign < 0 else pair[0] > 0) else
                           "contradicted" if (pair[0] > 0 if sign < 0 else pair[1] < 0) else "not separated")
                out.append({"finding": text, "a": a, "b": base, "difference": pair, "verdict": verdict})
    return out


def timing(times: list[dict]) -> dict:
    """Median and mean seconds per part over the frames after the first (the first compiles)."""
    later = times[1:] or times
    return {k: {"median": float(np.median([t[k] for t in later])), "mean": float(np.mean([t[k] for t in later]))}
            for k in later[0]}


def across(networks: dict, replicates: dict) -> dict:
    """The stronger network against the weaker on the same frames, paired: every row's envelope AP and
    FPR95 difference, and per finding both verdicts and how its gap changed (``difference_change``)."""
    strong, weak = replicates[STRONGER], replicates[WEAKER]
    rows = [{"score": name, "ap_difference": network_difference(strong, weak, name, "ap_envelope"),
             "fpr_difference": network_difference(strong, weak, name, "fpr_at_tpr")} for name in ROWS]
    changes = [{"finding": f["finding"], WEAKER: g["verdict"], STRONGER: f["verdict"],
                "change": difference_change(strong, weak, f["a"], f["b"],
                                            "fpr_at_tpr" if "FPR95" in f["finding"] else "ap_envelope")}
               for f, g in zip(networks[STRONGER]["findings"], networks[WEAKER]["findings"])]
    return {"rows": rows, "findings": changes}


def network_run(network: str, tracks: tuple[str, ...] | None = None, log=print) -> tuple[dict, dict, dict]:
    """One network on every track of ``tracks``: ``(results[track], replicates[track], labels[track])``;
    each track's frames resampled with ``draws(frames)`` (the same draws in every process: paired)."""
    _, predict = NETWORKS[network]()
    results, replicates, labels_of = {}, {}, {}
    for track, root in sorted(selected_tracks(tracks).items(), key=lambda item: item[0] != "RoadObstacle21"):
        scores, labels, times = track_scores(predict, root, lambda line: log(f"{network} {line}"))
        table, replicates[track] = with_intervals(scores, labels, draws(len(labels)))
        del scores
        labels_of[track] = labels
        results[track] = {"methods": table, "findings": findings(replicates[track]), "seconds": timing(times)}
    return results, replicates, labels_of


def main(tracks: list[str] | None = None) -> dict:
    """Both networks at once (``per_network``) on ``tracks`` (default all), then paired across."""
    selected_tracks(tracks)  # a wrong name fails before any work
    runs = per_network(functools.partial(network_run, tracks=tracks))
    results = {"replicates": REPLICATES}
    for network, (run, _, labels_of) in runs.items():
        for track, entry in run.items():
            labels = labels_of[track]
            same_frames(runs[WEAKER][2][track], labels, track)
            share = float(np.mean(np.concatenate(labels) == 1))  # a random score's AP
            results.setdefault(track, {"frames": len(labels), "anomaly_share": share, "networks": {}})
            results[track]["networks"][network] = entry
    for track in runs[WEAKER][1]:
        results[track]["across"] = across(results[track]["networks"], {network: runs[network][1][track]
                                                                       for network in NETWORKS})
    write_json_atomic(HERE / f"{NAME}.json", results)
    write_bytes_atomic(HERE / f"{NAME}.md", markdown(results).encode())
    return results


def _pct(v: float) -> str:
    return f"{100 * v:.1f}"


def _span(pair, digits: int = 1) -> str:
    return f"[{100 * pair[0]:.{digits}f}, {100 * pair[1]:.{digits}f}]"


def markdown(results: dict) -> str:
    lines = ["# MMF's post-processor (Eq. 6) on real uncertainty maps (ESPNet and ERFNet, the authors' Cityscapes "
             "weights)", "",
             "Written by `python -m experiments.real_mmf_post`. Network input 1024 wide (both networks' training "
             "scale; ESPNet's 20 channels, ERFNet's 19 trainIds); entropy (Eq. 1, / log2 C) "
             "and softmax distance (Eq. 2) resized bilinearly to the native frame; Eq. 6 there over SLIC with the "
             "scaled step (K ~ 2048): on the RGB frame, the same connected, or on the map itself. AP is the "
             "envelope AP (MMF Eq. 7), step AP beside it; FPR95 at the first point with TPR >= 95%; in %, pooled "
             f"over non-void pixels (RoadObstacle21: the road region); [95% interval] from {results['replicates']} "
             "bootstrap resamples of frames, the same draws for every row of both networks (paired, also across "
             "networks). Findings use paired intervals of the difference (held: beyond 0 in "
             "the paper's direction). The paper's Table 2 (its ablation, with the post-processor row) is an image "
             "in seeds/003: its values are not in the text; the text says the post-processor improves FPR95 "
             "considerably on both sets and AP less (its input is the dissimilarity net's map, not an uncertainty "
             "map). The text's numbers around it (Obstacle Track / Lost and Found, ROI = road, AP / FPR95): the "
             "framework without assistant maps and post-processor 28.29 / 15.24 and 31.11 / 16.03; full MMF "
             "(Table 1) 70.93 / 4.16 and 80.04 / 5.31; Table 1's Softmax Entropy row (their segmenter): "
             "55.41 / 5.28.", ""]
    for track in ("RoadObstacle21", "RoadAnomaly21"):
        if track not in results:
            lines += [f"## {track}", "", "Not in this run (`--tracks`).", ""]
            continue
        r = results[track]
        nets = [n for n in NETWORKS if n in r["networks"]]  # JSON sorts keys: the table's order
        rows = {row["score"]: row for row in r.get("across", {}).get("rows", [])}
        lines += [f"## {track} ({r['frames']} frames)", "",
                  f"Anomalous share of the scored pixels (the AP of a random score): {100 * r['anomaly_share']:.2f}%.", "",
                  "| score | " + " | ".join(f"{n} AP (envelope) | {n} FPR95 | {n} AP (step)" for n in nets)
                  + (f" | {STRONGER} - {WEAKER}: AP (envelope); FPR95 |" if rows else " |"),
                  "|---|" + "---|---|---|" * len(nets) + ("---|" if rows else "")]
        for name in ROWS:
            cells = [f"{_pct(m['ap_envelope'])} {_span(m['interval']['ap_envelope'])} | "
                     f"{_pct(m['fpr_at_tpr'])} {_span(m['interval']['fpr_at_tpr'])} | "
                     f"{_pct(m['ap'])} {_span(m['interval']['ap'])}" for m in (r["networks"][n]["methods"][name] for n in nets)]
            change = [f"{_span(rows[name]['ap_difference'])}; {_span(rows[name]['fpr_difference'])}"] if rows else []
            lines.append(f"| {name} | " + " | ".join(cells + change) + " |")
        changes = {c["finding"]: c for c in r.get("across", {}).get("findings", [])}
        lines += ["", "| finding (paired difference, points) | " + " | ".join(f"{n}: 95% interval | {n}: verdict" for n in nets)
                  + (f" | change {STRONGER} - {WEAKER} |" if changes else " |"),
                  "|---|" + "---|---|" * len(nets) + ("---|" if changes else "")]
        found = [r["networks"][n]["findings"] for n in nets]
        for i, first in enumerate(found[0]):
            cells = [f"{_span(f[i]['difference'], 3)} | {f[i]['verdict']}" for f in found]
            change = [_span(changes[first["finding"]]["change"], 3)] if changes else []
            lines.append(f"| {first['finding']} | " + " | ".join(cells + change) + " |")
        lines.append("")
        for network, f in zip(nets, found):
            held, against = sum(x["verdict"] == "held" for x in f), sum(x["verdict"] == "contradicted" for x in f)
            lines.append(f"{network}: {held} of {len(f)} findings held, {against} contradicted.")
        if changes:
            changed = [c["finding"] for c in changes.values() if c[WEAKER] != c[STRONGER]]
            lines.append(f"The stronger network changes the verdict of {len(changed)} of {len(changes)} findings"
                         + (": " + "; ".join(changed) + "." if changed else "."))
        lines += ["", "Seconds per frame (median over frames 2..N; 2 CPU cores shared with other jobs, XLA:CPU; "
                  "\"connected\" includes its own SLIC; \"SLIC on the map\" segments both maps; the networks ran at once, "
                  "each in its own process): "
                  + "; ".join(f"{n}: " + ", ".join(f"{k} {r['networks'][n]['seconds'][k]['median']:.2f}" for k in TIMES)
                              for n in nets) + ".", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown(main(arguments().tracks)))
