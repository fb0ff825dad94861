"""ESPNet's extra void channel (19) and the anomaly scores: with it, without it, or as evidence.

    python -m experiments.real_espnet_void          # writes real_espnet_void.json / .md beside this file

The authors' Cityscapes weights have 20 output channels: the 19 trainIds and a class they trained
on Cityscapes' void pixels (ego vehicle, borders, unlabelled objects). Each score is computed
  * over all 20 channels ("20"),
  * over the 19 trainId channels only, channel 19 dropped ("19"),
  * for MSP, also as 1 - max_{c<19} softmax over all 20 ("19 of 20": void's mass counts as anomalous),
  * and the void probability softmax_19 alone,
on RoadAnomaly21 and RoadObstacle21 (road region) at their native size, pooled over pixels, with
95% bootstrap intervals over frames and paired intervals for "19" minus "20".
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from experiments.real_common import HERE, TRAIN_IDS, anomaly_tracks, espnet, score_frames, with_intervals
from experiments.stats import REPLICATES, difference, draws
from jaxanom.app.scoring import inputs_of
from jaxanom.method_registry import score
from jaxanom.io import write_bytes_atomic, write_json_atomic

NAME = "real_espnet_void"
PAIRS = (("msp 19", "msp 20"), ("msp 19 of 20", "msp 20"), ("max_logit 19", "max_logit 20"),
         ("entropy 19", "entropy 20"), ("energy 19", "energy 20"))


def msp_19_of_20(logits):
    """1 - max_{c<19} softmax(logits)_c as s / (1 + s), s = sum over the other 19 channels of
    exp(l_c - l_top) (exact where 1 - p would round to 0, as ``jaxanom.scores.msp``)."""
    top = jnp.argmax(logits[..., :TRAIN_IDS], axis=-1)[..., None]
    top_logit = jnp.take_along_axis(logits, top, -1)
    s = jnp.where(jnp.arange(logits.shape[-1]) == top, 0.0, jnp.exp(logits - top_logit)).sum(-1)
    return s / (1.0 + s)


@jax.jit
def score_maps(logits):
    """Every row's map of one frame's logits (H, W, 20): the registered methods over all 20 channels and
    over the 19 trainIds, "msp 19 of 20", and the registered ``void`` method (channel 19's probability)."""
    full, trainids = inputs_of({"logits": logits[None]}), inputs_of({"logits": logits[None, ..., :TRAIN_IDS]})
    maps = {}
    for name in ("msp", "max_logit", "entropy", "energy"):
        maps[f"{name} 20"], maps[f"{name} 19"] = score(name, full)[0], score(name, trainids)[0]
        if name == "msp":
            maps["msp 19 of 20"] = msp_19_of_20(logits)
    maps["void probability"] = score("void", full)[0]
    return maps


def main() -> dict:
    _, predict = espnet()
    results = {}
    for track, root in anomaly_tracks().items():
        scores, labels = score_frames(predict, root, score_maps)
        table, replicates = with_intervals(scores, labels, draws(len(labels)))
        paired = {f"{a} - {b}": {m: difference(replicates, a, b, m) for m in ("ap", "fpr_at_tpr")} for a, b in PAIRS}
        results[track] = {"frames": len(labels), "methods": table, "differences": paired}
        del scores
    results["replicates"] = REPLICATES
    write_json_atomic(HERE / f"{NAME}.json", results)
    write_bytes_atomic(HERE / f"{NAME}.md", markdown(results).encode())
    return results


def _pct(value: float) -> str:
    return f"{100 * value:.1f}"


def markdown(results: dict) -> str:
    lines = ["# ESPNet's void channel in the anomaly scores", "",
             "Written by `python -m experiments.real_espnet_void`. AP and FPR at 95% TPR (%), pooled over the "
             f"non-void pixels; [95% interval] from {results['replicates']} bootstrap resamples of frames.", ""]
    for track in ("RoadAnomaly21", "RoadObstacle21"):
        r = results[track]
        lines += [f"## {track} ({r['frames']} frames)", "", "| score | AP | FPR95 |", "|---|---|---|"]
        for name, m in r["methods"].items():
            ap, fpr = m["interval"]["ap"], m["interval"]["fpr_at_tpr"]
            lines.append(f"| {name} | {_pct(m['ap'])} [{_pct(ap[0])}, {_pct(ap[1])}] | "
                         f"{_pct(m['fpr_at_tpr'])} [{_pct(fpr[0])}, {_pct(fpr[1])}] |")
        lines += ["", "| paired difference | AP | FPR95 |", "|---|---|---|"]
        for name, d in r["differences"].items():
            lines.append(f"| {name} | [{_pct(d['ap'][0])}, {_pct(d['ap'][1])}] | "
                         f"[{_pct(d['fpr_at_tpr'][0])}, {_pct(d['fpr_at_tpr'][1])}] |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown(main()))
