"""mIoU of the ERFNet authors' Cityscapes weights (the int8 redistribution, dequantised) on the 8
Cityscapes frames, with the protocol the road-anomaly repositories use for this network.

    python -m experiments.real_erfnet_miou          # writes real_erfnet_miou.json / .md beside this file

Each 2048x1024 frame is resized to 1024x512 with PIL's BILINEAR (a triangle filter widened to the
scale, i.e. antialiased; ``jaxanom.data.resize``), then scaled to [0, 1] (``ERFNet.normalize_input``). Labels
(trainIds, 255 ignored) are resized to 1024x512 by PIL's nearest neighbour (row 2i + 1 of the
original), or the logits upsampled to 2048x1024. The headline is the
argmax over the 19 trainId channels (the void channel dropped) at 1024x512; the other variants as
``experiments.real_espnet_miou``, whose code computes them.
"""
from __future__ import annotations

import numpy as np

from experiments.real_common import HERE, require_realdata
from experiments.real_espnet_miou import markdown, segmentation_results
from jaxanom.data.resize import resize_image_antialiased, resize_labels_nearest
from jaxanom.io import write_bytes_atomic, write_json_atomic

NAME = "real_erfnet_miou"
INPUT = (512, 1024)  # height, width
WEIGHTS = ("erfnet", "erfnet_cityscapes_int8.pth")
AUTHORS_VAL_MIOU = 72.2  # the float weights on the Cityscapes validation set (the authors' README)


def antialiased(image: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) -> uint8 ``INPUT`` by PIL's BILINEAR (a triangle filter widened when shrinking)."""
    return resize_image_antialiased(image, INPUT)


def nearest(label: np.ndarray) -> np.ndarray:
    """(H, W) -> ``INPUT`` by PIL's nearest neighbour (for 2048x1024: row 2i + 1 of the original)."""
    return resize_labels_nearest(label, INPUT)


def main() -> dict:
    from jaxanom.app.evaluate import predictor
    from jaxanom.weights import from_torch, read_state_dict

    model, variables = from_torch(read_state_dict(require_realdata(*WEIGHTS)), "erfnet-cityscapes")
    results = {**segmentation_results(predictor(model, variables), antialiased, nearest),
               "input": [INPUT[1], INPUT[0]], "weights": "/".join(WEIGHTS), "authors_val_miou_float": AUTHORS_VAL_MIOU}
    title = (f"ERFNet (authors' Cityscapes weights, int8 redistribution) on {len(results['frames'])} "
             "Cityscapes train frames")
    intro = (f"Written by `python -m experiments.{NAME}`. Input 1024x512 resized by PIL's BILINEAR (antialiased), "
             "RGB in [0, 1]; labels resized by nearest neighbour at pixel centres; classes that occur or are "
             "predicted averaged. "
             "The community's protocol drops the void channel: the row '1024x512, 19 trainIds' is the one to quote. "
             "These are training frames of the weights (optimistic); the authors report 72.2% on the Cityscapes "
             "validation set with the float weights.")
    write_json_atomic(HERE / f"{NAME}.json", results)
    write_bytes_atomic(HERE / f"{NAME}.md", markdown(results, title, intro, "1024x512").encode())
    return results


if __name__ == "__main__":
    main()
    print((HERE / f"{NAME}.md").read_text())
