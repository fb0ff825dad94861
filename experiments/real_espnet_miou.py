"""mIoU of the ESPNet authors' Cityscapes weights, converted to jaxanom, on the 8 Cityscapes frames.

    python -m experiments.real_espnet_miou          # writes real_espnet_miou.json / .md beside this file

Each 2048x1024 frame is resized bilinearly to 1024x512 (the authors' test input) and normalised
as the weights expect; the logits are compared with the fine labels (trainIds, 255 ignored) at
full resolution (logits upsampled bilinearly, half-pixel centres) and at 1024x512 (labels
resized by nearest neighbour). The prediction is the argmax over the 19 trainId channels, and
over all 20 (channel 19, the authors' void class, is then wrong wherever the label is a class).
mIoU averages the classes that occur or are predicted (``jaxanom.metrics.miou``), as the
Cityscapes scripts do over their whole validation set; with 8 frames some classes are absent, and a
class predicted on a few pixels but never labelled counts as 0, so the mean over the classes that
occur in the labels is given beside it.
``segmentation_results`` and ``markdown`` serve ``experiments.real_erfnet_miou`` too.
"""
from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from experiments.real_common import HERE, TRAIN_IDS, espnet, logits_of, require_realdata
from jaxanom.data.cityscapes import Cityscapes
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.metrics import confusion_matrix, confusion_scores
from jaxanom.nn.layers import resize_bilinear

NAME = "real_espnet_miou"
INPUT = (1024, 512)  # width, height
PAPER_MIOU = 60.3  # ESPNet paper, Table 2 (Cityscapes test set, 1024x512 input)


def main() -> dict:
    _, predict = espnet()
    resize_image = lambda image: cv2.resize(image, INPUT, interpolation=cv2.INTER_LINEAR)  # noqa: E731
    resize_label = lambda label: cv2.resize(label, INPUT, interpolation=cv2.INTER_NEAREST)  # noqa: E731
    results = {**segmentation_results(predict, resize_image, resize_label), "input": list(INPUT),
               "paper_miou_test": PAPER_MIOU}
    title = f"ESPNet (authors' Cityscapes weights) on {len(results['frames'])} Cityscapes train frames"
    intro = (f"Written by `python -m experiments.{NAME}`. Input 1024x512; classes that occur or are predicted "
             "averaged. These are training frames of the weights (optimistic); paper: 60.3% mIoU on the Cityscapes "
             "test set (ESPNet Table 2).")
    write_json_atomic(HERE / f"{NAME}.json", results)
    write_bytes_atomic(HERE / f"{NAME}.md", markdown(results, title, intro, "1024x512").encode())
    return results


def segmentation_results(predict, resize_image: Callable, resize_label: Callable) -> dict:
    """Confusion-matrix results of ``predict`` (uint8 RGB batches -> {"logits"}) on the Cityscapes
    frames: per key ``{full,input}_{19,20}`` (evaluated at 2048x1024 with the logits upsampled, or at
    the input size with ``resize_label``'s labels; argmax over the 19 trainIds or all 20 channels)
    the mIoU (classes occurring or predicted), the mIoU over the labelled classes, pixel accuracy,
    per-class IoUs and the pixels predicted void."""
    frames = Cityscapes(require_realdata("cityscapes8"), "train")
    matrices = {key: np.zeros((TRAIN_IDS + 1, TRAIN_IDS + 1), np.int64)
                for key in ("full_19", "full_20", "input_19", "input_20")}
    for frame in frames:
        image, label = frame["image"], frame["label"]
        logits = logits_of(predict, resize_image(image))
        full = np.asarray(resize_bilinear(logits[None], *label.shape)[0])
        for size, out, target in (("full", full, label), ("input", logits, resize_label(label))):
            for channels in (TRAIN_IDS, TRAIN_IDS + 1):
                prediction = out[..., :channels].argmax(-1)
                matrices[f"{size}_{channels}"] += np.asarray(confusion_matrix(prediction, target, TRAIN_IDS + 1))
    results = {"frames": [frames[i]["name"] for i in range(len(frames))]}
    for key, matrix in matrices.items():
        scores = confusion_scores(matrix, TRAIN_IDS)  # the 19 trainIds scored; void is never a label
        iou = scores["iou"]
        labelled = matrix.sum(1)[:TRAIN_IDS] > 0  # rows are labels
        results[key] = {"miou": scores["miou"], "miou_labelled": float(np.mean(iou[labelled])),
                        "pixel_accuracy": scores["pixel_accuracy"],
                        "per_class_iou": [None if np.isnan(v) else float(v) for v in iou],
                        "void_predicted_pixels": int(matrix[:, TRAIN_IDS].sum())}
    return results


def markdown(results: dict, title: str, intro: str, input_size: str) -> str:
    rows = [("full", "2048x1024 (logits upsampled)"), ("input", f"{input_size} (labels resized)")]
    lines = [f"# {title}", "", intro, "",
             "| evaluated at | argmax over | mIoU % | mIoU % over the labelled classes | pixel accuracy % "
             "| pixels predicted void |", "|---|---|---|---|---|---|"]
    for key, where in rows:
        for channels, what in ((TRAIN_IDS, "19 trainIds"), (TRAIN_IDS + 1, "20 channels")):
            r = results[f"{key}_{channels}"]
            lines.append(f"| {where} | {what} | {100 * r['miou']:.1f} | {100 * r['miou_labelled']:.1f} | "
                         f"{100 * r['pixel_accuracy']:.1f} | "
                         f"{r['void_predicted_pixels']} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
    print((HERE / f"{NAME}.md").read_text())
