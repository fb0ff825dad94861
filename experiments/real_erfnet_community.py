"""The community's ERFNet road-anomaly table, reproduced with ``evaluate --protocol erfnet-community``.

    python -m experiments.real_erfnet_community     # writes real_erfnet_community.json / .md beside this file

Many public repositories evaluate the ERFNet authors' Cityscapes weights on the SegmentMeIfYouCan
validation frames with one protocol, and four of them independently report the numbers in
``PUBLISHED`` (float weights). The protocol (``jaxanom.protocols``, ``erfnet-community``): RGB
resized to 512x1024 with PIL's BILINEAR (antialiased), in [0, 1] without mean or std; the void
output dropped; labels resized to 512x1024 by PIL's NEAREST; frames without an anomaly pixel
skipped; pixels pooled over frames; AP as scikit-learn's average precision, FPR95 as ood-metrics'
``fpr_at_95_tpr`` (interpolated). Their MSP is 1 - max softmax and their max entropy divides by
log 19: monotone maps of jaxanom's ``msp`` and ``entropy``, which leave AP and FPR unchanged.

This runs the same application functions as ``jaxanom evaluate --run RUN --dataset smiyc
--protocol erfnet-community`` on the int8 redistribution of the weights (dequantised), so the
comparison allows about 1 AP point and 2 FPR95 points from the float weights' numbers.
The ``void`` row (softmax probability of the 20th output) is ours: the authors trained that output
with loss weight 0.
"""
from __future__ import annotations

from experiments.real_common import HERE, require_realdata
from jaxanom.io import write_bytes_atomic, write_json_atomic

NAME = "real_erfnet_community"
WEIGHTS = ("erfnet", "erfnet_cityscapes_int8.pth")
METHODS = ("msp", "max_logit", "entropy", "void")
TRACKS = {"RoadAnomaly21": "anomaly", "RoadObstacle21": "obstacle"}
# AuPRC / FPR95 in % of the float weights under this protocol, as four repositories report them.
PUBLISHED = {"RoadAnomaly21": {"msp": (29.10, 62.51), "max_logit": (38.32, 59.34), "entropy": (31.01, 62.59)},
             "RoadObstacle21": {"msp": (2.71, 64.97), "max_logit": (4.63, 48.44), "entropy": (3.05, 65.60)}}
# Checked on RoadObstacle21 MSP while its FPR95 stayed 8 points above the published one; none of
# these explains it (measured here, one run each, when the protocol's image resize was the
# floating-point triangle filter, within one grey level of PIL's, which gave 2.48 / 73.47; the
# protocol now resizes with PIL itself: 2.48 / 72.90):
CHECKED = ("decoding the WebP frames with PIL instead of OpenCV: identical pixels, 2.48 / 73.47",
           "PIL's own BILINEAR resize instead of the floating-point triangle filter: 2.48 / 72.90 (now the protocol's)",
           "the softmax over all 20 outputs, void included: 2.48 / 73.75",
           "the scores upsampled to the labels' 1920x1080 instead of labels resized: 2.51 / 73.65",
           "1024x576 input (aspect kept), area filter: 1.43 / 82.52",
           "the void (255, off-road) pixels counted as normal: 0.31 / 86.06")
LABELS = {"msp": "MSP", "max_logit": "max logit", "entropy": "max entropy", "void": "void classifier"}


def main() -> dict:
    from jaxanom.app.evaluate import anomaly_results, dataset_reader, predictor, protocol_predictions
    from jaxanom.protocols import get_protocol
    from jaxanom.weights import from_torch, read_state_dict

    model, variables = from_torch(read_state_dict(require_realdata(*WEIGHTS)), "erfnet-cityscapes")
    predict = predictor(model, variables)
    protocol = get_protocol("erfnet-community")
    results = {"protocol": protocol.name, "weights": "/".join(WEIGHTS), "tracks": {}}
    for track in TRACKS:
        source = dataset_reader("smiyc", str(require_realdata(track)))
        skipped: list[str] = []
        metrics, _ = anomaly_results(protocol_predictions(predict, source, protocol, skipped), METHODS,
                                     fpr_convention=protocol.fpr_convention, ap_convention=protocol.ap_convention,
                                     drop_void=protocol.drop_void)
        results["tracks"][track] = {
            "frames": len(source), "skipped": skipped,
            "ours": {name: {"ap": 100 * metrics[name]["ap"], "fpr95": 100 * metrics[name]["fpr_at_tpr"],
                            "auroc": 100 * metrics[name]["auroc"]} for name in METHODS},
            "published": {name: {"ap": ap, "fpr95": fpr} for name, (ap, fpr) in PUBLISHED[track].items()}}
        print(f"{track}: done ({len(source) - len(skipped)} of {len(source)} frames counted)")
    write_json_atomic(HERE / f"{NAME}.json", results)
    write_bytes_atomic(HERE / f"{NAME}.md", markdown(results).encode())
    return results


def markdown(results: dict) -> str:
    lines = ["# ERFNet on the SegmentMeIfYouCan validation frames: the community's table reproduced", "",
             f"Written by `python -m experiments.{NAME}` (protocol `{results['protocol']}`, weights "
             f"`{results['weights']}`, dequantised). AP and FPR95 in %; 'published': the float weights' numbers "
             "as four public repositories report them under this protocol; Δ: ours minus published "
             "(tolerance for the int8 weights: about 1 AP point, 2 FPR95 points).", ""]
    for track, row in results["tracks"].items():
        counted = row["frames"] - len(row["skipped"])
        lines += [f"## {track} ({counted} of {row['frames']} frames counted)", "",
                  "| score | AP | FPR95 | AUROC | published AP / FPR95 | Δ AP | Δ FPR95 |", "|---|---|---|---|---|---|---|"]
        for name, ours in row["ours"].items():
            published = row["published"].get(name)
            paper = f"{published['ap']:.2f} / {published['fpr95']:.2f}" if published else "(not published)"
            delta = (f"{ours['ap'] - published['ap']:+.2f} | {ours['fpr95'] - published['fpr95']:+.2f}"
                     if published else " | ")
            lines.append(f"| {LABELS[name]} | {ours['ap']:.2f} | {ours['fpr95']:.2f} | {ours['auroc']:.2f} | "
                         f"{paper} | {delta} |")
        lines.append("")
    lines += ["The images are resized by PIL itself (`jaxanom.data.resize`), as the community's scripts do: the "
              "floating-point triangle filter used before, within one grey level of PIL's on 13-17% of the pixels, "
              "put AP 0.17 to 0.21 points higher on RoadAnomaly21 (MSP 29.97, max logit 39.11, max entropy 31.84). "
              "`evaluate --protocol erfnet-community` now equals a PIL + PyTorch + scikit-learn rendering of the "
              "community's evaluation (`tests/community_reference.py`) to float32 rounding of the network.", "",
              "RoadAnomaly21 agrees within the tolerance. On RoadObstacle21 AP agrees (within 0.3 points) but FPR95 "
              "is 6 to 8 points above the published values, beyond the 2 points the int8 weights were expected to "
              "cost. "
              "What was ruled out (RoadObstacle21, MSP, AP / FPR95; measured with the former resize):", "",
              *(f"- {item}" for item in CHECKED), "",
              "What explains it: the weights. These are the int8 redistribution; `real_erfnet_int8_spread.md` "
              "evaluates 7 networks whose weights lie within half an int8 step of them (where the float weights lie): "
              "their RoadObstacle21 FPR95 moves by up to +9 to +12 points with AP within 0.7, on RoadAnomaly21 by up "
              "to +5, so a gap of this size and sign is what one rounding of the weights can make (measured with the "
              "former resize and not rerun: its grid row is this table's before the change). The protocol "
              "itself was checked against a public repository's own results log (ERFNet, float weights, "
              "RoadObstacle21 MSP with this resize: 2.71 / 65.05 and 65.30; without the resize: 0.64-0.67 / 89.7-96.4).", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
    print((HERE / f"{NAME}.md").read_text())
