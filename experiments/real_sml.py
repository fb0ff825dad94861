"""SML Tables 3 and 7 on real frames with two networks: the ESPNet and ERFNet authors' Cityscapes
weights (``real_common.NETWORKS``) on RoadAnomaly21 and RoadObstacle21, MSP / max logit / entropy /
energy / SML, each without and with boundary suppression + dilated smoothing; SML statistics fitted
on the 8 Cityscapes frames under every statistics policy; 95% bootstrap intervals over frames, paired
for the findings and across the networks (the same frame draws for every row of both).

    python -m experiments.real_sml [--tracks RoadAnomaly21]   # writes real_sml.json / .md beside this file

Both networks run at once, each in its own process. ``--tracks RoadAnomaly21`` took 20.7 min wall on
2 CPU cores shared with ~25 other processes; RoadObstacle21 scores about twice its pixels (19.2M
against 8.9M) in three times the frames.

Set-up (decisions in docs/decisions/espnet.md, real-networks.md and sml.md):
* Input: every frame resized to 1024 pixels wide (height rounded to a multiple of 8), the scale
  both networks were trained at (Cityscapes' 2048x1024 halved, 1024x512); the Cityscapes frames at
  1024x512. On RoadAnomaly21 this scale gives ESPNet's max logit AP 28.3 / FPR95 63.6 against
  23.8 / 72.7 at the native 1280x720 (measured while setting this up). ESPNet scores all 20
  channels (its void channel included, as measured by ``real_espnet_void``); ERFNet its 19
  trainIds (its void channel was trained with loss weight 0).
* Post-processing (SML Eqs. 6-8 with the paper's width 4, 4 iterations, 7x7 Gaussian, dilation 6)
  runs on the network's output (1024 wide), the resolution the paper's parameters were designed
  for (its 2048x1024 Cityscapes frames at the network's stride-8 logits upsampled: boundaries a few
  pixels wide at ~1000-2000 pixels width); the maps are then resized bilinearly to the labels' size.
* Metrics pooled over the non-void pixels of each track (RoadObstacle21: the road region, its
  labels are void elsewhere). A finding of the paper "holds" when the paired 95% interval of the
  difference lies beyond +-0.1 points in the paper's direction; "contradicted" when it lies beyond
  them the other way (differences inside +-0.1 points are taken as none).
"""
from __future__ import annotations

import argparse
import functools

import cv2
import numpy as np

from experiments.real_common import (HERE, NETWORKS, logits_of, per_network, require_realdata, same_frames,
                                     score_frames, selected_tracks, with_intervals)
from experiments.stats import REPLICATES, difference, difference_change, draws, network_difference
from jaxanom import scores as S
from jaxanom import sml
from jaxanom.data.cityscapes import Cityscapes
from jaxanom.io import write_bytes_atomic, write_json_atomic

NAME = "real_sml"
WIDTH = 1024
# The paper's estimate and the two pooled policies at the settings that came out best with ESPNet (its
# earlier run also had shrink 1e4 and 1e5, each separably worse than shrink 1e6: docs/decisions/sml.md).
POLICIES = {"none": dict(policy="none", missing="pooled"), "min_count 1e4": dict(policy="min_count", min_count=1e4),
            "shrink 1e6": dict(policy="shrink", strength=1e6)}
BASES = {"MSP": S.msp, "max logit": S.max_logit, "entropy": S.entropy, "energy": S.energy}
POST = " + post"  # boundary suppression + dilated smoothing
PAPER = "none"  # the policy of the paper (its per-class estimate)
MARGIN = 0.001  # a difference counts when its 95% interval excludes [-0.1, 0.1] points (negligible otherwise)
ROWS = (*(name + suffix for name in BASES for suffix in ("", POST)),  # the tables' rows, as score_maps
        *(f"SML ({policy}){suffix}" for policy in POLICIES for suffix in ("", POST, " + suppression", " + smoothing")))
STRONGER, WEAKER = "ERFNet", "ESPNet"  # 72% and 62% mIoU on the 8 Cityscapes frames


def fit_statistics(predict) -> tuple[dict, dict]:
    """Per policy the finalised (mean, std), and per class the predicted pixels (the 8 frames)."""
    frames = Cityscapes(require_realdata("cityscapes8"), "train")
    stats = sml.fit_stats(logits_of(predict, cv2.resize(frames[i]["image"], (WIDTH, WIDTH // 2),
                                                        interpolation=cv2.INTER_AREA)) for i in range(len(frames)))
    finals = {name: sml.stats_finalize(stats, **options) for name, options in POLICIES.items()}
    return finals, {"count": np.asarray(stats.count).astype(int).tolist()}


def score_maps(logits: np.ndarray, finals: dict) -> dict[str, np.ndarray]:
    """Every row's anomaly map (higher = more anomalous) at the network's output size."""
    prediction = np.asarray(logits.argmax(-1), np.int32)
    maps = {}
    for name, fn in BASES.items():
        maps[name] = fn(logits)
        maps[name + POST] = sml.postprocess(maps[name], prediction)
    for policy, (mean, std) in finals.items():
        standardized, _ = sml.standardized_max_logit(logits, mean, std)
        maps[f"SML ({policy})"] = -standardized
        maps[f"SML ({policy}){POST}"] = -sml.postprocess(standardized, prediction)
        maps[f"SML ({policy}) + suppression"] = -sml.postprocess(standardized, prediction, smooth=False)
        maps[f"SML ({policy}) + smoothing"] = -sml.postprocess(standardized, prediction, suppress=False)
    return maps


def findings(replicates: dict, policy: str) -> list[dict]:
    """The paper's claims, with SML's statistics under ``policy``, as paired differences ``a - b``."""
    sml_, post = f"SML ({policy})", f"SML ({policy}){POST}"
    claims = [
        ("Table 3: SML beats max logit", sml_, "max logit", "both"),
        ("Table 3: SML + suppression + smoothing beats max logit", post, "max logit", "both"),
        ("Table 3: suppression improves SML (paper: AP +4, FPR95 -1)", f"{sml_} + suppression", sml_, "both"),
        ("Table 3: smoothing alone raises SML's AP", f"{sml_} + smoothing", sml_, "ap"),
        ("Table 3: smoothing alone raises SML's FPR95 slightly", f"{sml_} + smoothing", sml_, "fpr worse"),
        ("Table 3: suppression + smoothing beats suppression alone", post, f"{sml_} + suppression", "both"),
        ("Table 3: suppression + smoothing beats smoothing alone", post, f"{sml_} + smoothing", "both"),
        ("Table 7: post-processing improves SML", post, sml_, "both"),
        ("Table 7: AP of max logit above MSP", "max logit", "MSP", "ap"),
        ("Table 7: AP of SML above max logit", sml_, "max logit", "ap"),
        ("Table 7: SML + post-processing above max logit + post-processing", post, f"max logit{POST}", "both"),
        ("Table 7: post-processing does not improve MSP", f"MSP{POST}", "MSP", "not better"),
        ("Table 7: post-processing does not improve max logit", f"max logit{POST}", "max logit", "not better"),
    ]
    out = []
    for text, a, b, kind in claims:
        ap, fpr = difference(replicates, a, b, "ap"), difference(replicates, a, b, "fpr_at_tpr")
        ap_up, ap_down, fpr_up, fpr_down = ap[0] > MARGIN, ap[1] < -MARGIN, fpr[0] > MARGIN, fpr[1] < -MARGIN
        verdict = {"both": "held" if ap_up and fpr_down else "contradicted" if ap_down or fpr_up else "not separated",
                   "ap": "held" if ap_up else "contradicted" if ap_down else "not separated",
                   "fpr worse": "held" if fpr_up else "contradicted" if fpr_down else "not separated",
                   "not better": "contradicted" if ap_up or fpr_down else "held (no separated gain)"}[kind]
        out.append({"finding": text, "a": a, "b": b, "ap_difference": ap, "fpr_difference": fpr, "verdict": verdict})
    return out


def policy_comparison(replicates: dict) -> list[dict]:
    """Every pair of statistics policies (SML alone and with post-processing), and each against max logit."""
    names = list(POLICIES)
    pairs = [(f"SML ({a}){suffix}", f"SML ({b}){suffix}") for i, a in enumerate(names) for b in names[i + 1:]
             for suffix in ("", POST)]
    pairs += [(f"SML ({a}){suffix}", f"max logit{suffix}") for a in names for suffix in ("", POST)]
    return [{"a": a, "b": b, "ap_difference": difference(replicates, a, b, "ap"),
             "fpr_difference": difference(replicates, a, b, "fpr_at_tpr")} for a, b in pairs]


def across(networks: dict, replicates: dict) -> dict:
    """The stronger network against the weaker on the same frames, paired: every row's difference, and per
    finding and policy both verdicts and how the finding's gap changed (``difference_change``)."""
    strong, weak = replicates[STRONGER], replicates[WEAKER]
    rows = [{"score": name, "ap_difference": network_difference(strong, weak, name, "ap"),
             "fpr_difference": network_difference(strong, weak, name, "fpr_at_tpr")}
            for name in networks[STRONGER]["methods"]]
    changes = [{"finding": f["finding"], "policy": policy, WEAKER: g["verdict"], STRONGER: f["verdict"],
                "ap_change": difference_change(strong, weak, f["a"], f["b"], "ap"),
                "fpr_change": difference_change(strong, weak, f["a"], f["b"], "fpr_at_tpr")}
               for policy in POLICIES
               for f, g in zip(networks[STRONGER]["findings"][policy], networks[WEAKER]["findings"][policy])]
    return {"rows": rows, "findings": changes}


def network_run(network: str, tracks: tuple[str, ...] | None = None, log=print) -> tuple[dict, dict, dict]:
    """One network on every track of ``tracks``: ``(results, replicates[track], labels[track])``; each
    track's frames resampled with ``draws(frames)`` (deterministic: the same draws in every process, so
    paired across networks)."""
    _, predict = NETWORKS[network]()
    finals, counts = fit_statistics(predict)
    results = {"class_pixels": counts["count"], "tracks": {},
               "statistics": {p: {"mean": np.asarray(m).tolist(), "std": np.asarray(s).tolist()}
                              for p, (m, s) in finals.items()}}
    replicates, labels_of = {}, {}
    for track, root in selected_tracks(tracks).items():
        scores, labels = score_frames(predict, root, lambda logits: score_maps(logits, finals),
                                      lambda line: log(f"{network} {line}"), width=WIDTH)
        table, replicates[track] = with_intervals(scores, labels, draws(len(labels)))
        del scores
        labels_of[track] = labels
        results["tracks"][track] = {"methods": table, "policies": policy_comparison(replicates[track]),
                                    "findings": {policy: findings(replicates[track], policy) for policy in POLICIES}}
    return results, replicates, labels_of


def main(tracks: list[str] | None = None) -> dict:
    """Both networks at once (``per_network``) on ``tracks`` (default all), then paired across."""
    selected_tracks(tracks)  # a wrong name fails before any work
    runs = per_network(functools.partial(network_run, tracks=tracks))
    results = {"input_width": WIDTH, "replicates": REPLICATES, "networks": {}}
    for network, (run, _, labels_of) in runs.items():
        results["networks"][network] = {k: v for k, v in run.items() if k != "tracks"}
        for track, entry in run["tracks"].items():
            same_frames(runs[WEAKER][2][track], labels_of[track], track)
            results.setdefault(track, {"frames": len(labels_of[track]), "networks": {}})["networks"][network] = entry
    for track in runs[WEAKER][1]:
        results[track]["across"] = across(results[track]["networks"], {network: runs[network][1][track]
                                                                       for network in NETWORKS})
    write_json_atomic(HERE / f"{NAME}.json", results)
    write_bytes_atomic(HERE / f"{NAME}.md", markdown(results).encode())
    return results


def _pct(v: float) -> str:
    return f"{100 * v:.1f}"


def _span(pair) -> str:
    return f"[{_pct(pair[0])}, {_pct(pair[1])}]"


def _cell(pair_ap, pair_fpr) -> str:
    return f"{_span(pair_ap)}; {_span(pair_fpr)}"


def markdown(results: dict) -> str:
    networks = [n for n in NETWORKS if n in results["networks"]]  # JSON sorts keys: the table's order
    lines = ["# SML Tables 3 and 7 on real frames (ESPNet and ERFNet, the authors' Cityscapes weights)", "",
             "Written by `python -m experiments.real_sml`. Both networks were trained at 1024x512: frames resized to "
             "1024 wide (aspect kept, area filter), the same input for both; ESPNet scores its 20 channels, ERFNet its "
             "19 trainIds (its void channel was trained with weight 0). Statistics from the 8 Cityscapes frames at "
             "1024x512; post-processing (\" + post\": boundary suppression + dilated smoothing) at the network's "
             "output size; AP and FPR at 95% TPR in %, pooled over non-void pixels at the labels' size; [95% interval] "
             f"from {results['replicates']} bootstrap resamples of frames, the same draws for every row of both "
             "networks (paired, also across networks). Verdicts use paired intervals of the difference (held: the "
             "interval lies beyond +-0.1 points in the paper's direction; contradicted: beyond them the other way). "
             "The paper's tables (Fishyscapes Lost & Found, DeepLabV3+ R101) are images in seeds/002; its text gives "
             "the directions and, for suppression on SML, AP +4 and FPR95 -1.", ""]
    for network in networks:
        lines.append(f"{network}: pixels predicted per class on the 8 statistics frames: "
                     + ", ".join(str(c) for c in results["networks"][network]["class_pixels"]) + ".")
    lines.append("")
    for track in ("RoadAnomaly21", "RoadObstacle21"):
        if track not in results:
            lines += [f"## {track}", "", "Not in this run (`--tracks`).", ""]
            continue
        r = results[track]
        nets = [n for n in networks if n in r["networks"]]
        rows = {row["score"]: row for row in r.get("across", {}).get("rows", [])}
        lines += [f"## {track} ({r['frames']} frames)", "",
                  "| score | " + " | ".join(f"{n} AP | {n} FPR95" for n in nets)
                  + (f" | {STRONGER} - {WEAKER}: AP; FPR95 |" if rows else " |"),
                  "|---|" + "---|---|" * len(nets) + ("---|" if rows else "")]
        for name in ROWS:
            cells = [f"{_pct(m['ap'])} {_span(m['interval']['ap'])} | {_pct(m['fpr_at_tpr'])} "
                     f"{_span(m['interval']['fpr_at_tpr'])}" for m in (r["networks"][n]["methods"][name] for n in nets)]
            change = [_cell(rows[name]["ap_difference"], rows[name]["fpr_difference"])] if rows else []
            lines.append(f"| {name} | " + " | ".join(cells + change) + " |")
        for network in nets:
            found = r["networks"][network]["findings"]
            lines += ["", f"{network}: findings per statistics policy: verdict (paired AP difference; FPR95 difference).",
                      "", "| finding | " + " | ".join(POLICIES) + " |", "|---|" + "---|" * len(POLICIES)]
            for i, first in enumerate(found[PAPER]):
                lines.append(f"| {first['finding']} | " + " | ".join(
                    f"{f['verdict']} ({_cell(f['ap_difference'], f['fpr_difference'])})"
                    for f in (found[policy][i] for policy in POLICIES)) + " |")
        if "across" in r:
            changed = [c for c in r["across"]["findings"] if c[WEAKER] != c[STRONGER]]
            lines += ["", f"The stronger network changes the verdict: {len(changed)} of {len(r['across']['findings'])} "
                      f"(finding, policy) verdicts differ between {WEAKER} and {STRONGER}. Change of the finding's "
                      f"paired difference ({STRONGER}'s minus {WEAKER}'s, same draws), in points:", "",
                      f"| finding | policy | {WEAKER} | {STRONGER} | AP change | FPR95 change |", "|---|---|---|---|---|---|"]
            lines += [f"| {c['finding']} | {c['policy']} | {c[WEAKER]} | {c[STRONGER]} | {_span(c['ap_change'])} | "
                      f"{_span(c['fpr_change'])} |" for c in changed]
        policies = [p["a"] + " - " + p["b"] for p in r["networks"][nets[0]]["policies"]]
        lines += ["", "| policy comparison (a - b) | " + " | ".join(f"{n} AP; FPR95 difference" for n in nets) + " |",
                  "|---|" + "---|" * len(nets)]
        for i, text in enumerate(policies):
            lines.append(f"| {text} | " + " | ".join(
                _cell(p["ap_difference"], p["fpr_difference"]) for p in (r["networks"][n]["policies"][i] for n in nets))
                + " |")
        lines.append("")
    return "\n".join(lines)


def arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracks", nargs="+", help="RoadAnomaly21 and/or RoadObstacle21 (default: both)")
    return parser.parse_args(argv)


if __name__ == "__main__":
    print(markdown(main(arguments().tracks)))
