"""The ERFNet authors' Cityscapes weights on CamVid test frames as they are, classes mapped.

    JAXANOM_CAMVID=/path/to/CamVid python -m experiments.real_camvid_as_is [--frames 40]

The starting point a CamVid fine-tune improves on (``docs/decisions/camvid.md``). Each of the
first ``--frames`` test frames (360x480, in the split list's order) is scored at its own size, at
720x960 and squashed to 512x1024 (bilinear; the prediction taken back to the native pixels by
nearest neighbour); the
argmax over the 19 trainIds (the void output dropped) becomes a CamVid class through
``jaxanom.data.camvid.CITYSCAPES_TO_CAMVID``; mIoU over CamVid's 11 classes (void pixels ignored).
Prints a markdown table (nothing written); a few minutes on 2 CPU cores.
"""
from __future__ import annotations

import argparse
import os

import cv2
import numpy as np

from experiments.real_common import REALDATA
from jaxanom.data.camvid import CITYSCAPES_TO_CAMVID, CLASS_NAMES, NUM_CLASSES, CamVid
from jaxanom.metrics import confusion_scores

WEIGHTS = REALDATA / "erfnet" / "erfnet_cityscapes_int8.pth"
SIZES = {"360x480 (native)": None, "720x960 (2x)": (720, 960), "512x1024 (squashed, its training size)": (512, 1024)}


def confusion(predict, frames, size) -> np.ndarray:
    """(12, 12) counts over ``frames``: rows CamVid labels, columns CamVid classes and 11 = a
    prediction with no CamVid class (none here: every trainId maps to one)."""
    total = np.zeros((NUM_CLASSES + 1, NUM_CLASSES + 1), np.int64)
    for frame in frames:
        image, label = frame["image"], frame["label"]
        if size is not None:
            image = cv2.resize(image, size[::-1], interpolation=cv2.INTER_LINEAR)
        trainids = np.asarray(predict(image[None])["logits"][0, ..., :19].argmax(-1))
        if size is not None:
            trainids = cv2.resize(trainids.astype(np.uint8), label.shape[::-1], interpolation=cv2.INTER_NEAREST)
        predicted = np.minimum(CITYSCAPES_TO_CAMVID[trainids], NUM_CLASSES)
        kept = label != 255
        total += np.bincount(label[kept].astype(np.int64) * (NUM_CLASSES + 1) + predicted[kept],
                             minlength=(NUM_CLASSES + 1) ** 2).reshape(NUM_CLASSES + 1, NUM_CLASSES + 1)
    return total


def main(root: str, count: int) -> str:
    from jaxanom.app.evaluate import predictor
    from jaxanom.data.frames import FirstFrames
    from jaxanom.weights import from_torch, read_state_dict

    model, variables = from_torch(read_state_dict(WEIGHTS), "erfnet-cityscapes")
    predict = predictor(model, variables)
    frames = FirstFrames(CamVid(root, "test"), count)
    lines = ["| input | mIoU | pixel accuracy | " + " | ".join(CLASS_NAMES) + " |",
             "|---|---|---|" + "---|" * NUM_CLASSES]
    for name, size in SIZES.items():
        scores = confusion_scores(confusion(predict, frames, size), NUM_CLASSES)
        lines.append(f"| {name} | {100 * scores['miou']:.1f} | {100 * scores['pixel_accuracy']:.1f} | "
                     + " | ".join(f"{100 * v:.1f}" for v in scores["iou"]) + " |")
    return (f"ERFNet, authors' Cityscapes weights (int8 file), on the first {len(frames)} CamVid test frames, "
            "IoU in %:\n\n" + "\n".join(lines))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", default=os.environ.get("JAXANOM_CAMVID"), help="the CamVid folder (JAXANOM_CAMVID)")
    parser.add_argument("--frames", type=int, default=40)
    args = parser.parse_args()
    if not args.root:
        parser.error("--root: the CamVid folder (or set JAXANOM_CAMVID)")
    print(main(args.root, args.frames))
