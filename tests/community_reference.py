"""An independent rendering of the community's ERFNet road-anomaly evaluation (PIL + PyTorch +
scikit-learn), the reference of ``jaxanom evaluate --protocol erfnet-community``.

What the public evaluation scripts do (``eval/evalAnomaly.py`` of the ERFNet course-project code
and its forks), written here without jaxanom: each image opened with PIL as RGB, resized with
``Resize((512, 1024), Image.BILINEAR)`` and ``ToTensor()`` (uint8 / 255 in float32); the int8
weights dequantised by torch into our PyTorch ERFNet (``torch_reference.ERFNetTorch``); the 19
non-void outputs; scores MSP = 1 - max softmax, max logit = -max logit, entropy of the softmax
(float64, from the float32 logits); labels opened with PIL and resized with ``Image.NEAREST``;
frames without an anomaly pixel (1) skipped; the pixels labelled 0 or 1 of every frame pooled;
AP as scikit-learn's ``average_precision_score``, FPR95 as ood-metrics' ``fpr_at_95_tpr``.

    python tests/community_reference.py WEIGHTS TRACK_FOLDER [FRAMES]   # prints AP / FPR95 in %
"""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from sklearn.metrics import average_precision_score, roc_curve

sys.path.insert(0, str(Path(__file__).resolve().parent))
from torch_reference import ERFNetTorch  # noqa: E402

SIZE = (512, 1024)  # (H, W) as torchvision's Resize takes it; PIL's resize takes (W, H)
METHODS = ("msp", "max_logit", "entropy")


def erfnet(weights: Path) -> ERFNetTorch:
    """The int8 file's weights, dequantised by torch, in the fused rendering (eval mode)."""
    with warnings.catch_warnings():  # torch's deprecation warnings while it rebuilds quantised tensors
        warnings.simplefilter("ignore")
        state = torch.load(weights, map_location="cpu", weights_only=True)
    net = ERFNetTorch(classes=20, fused=True).eval()
    wanted = net.state_dict()
    net.load_state_dict({k: (v.dequantize() if v.is_quantized else v) for k, v in state.items() if k in wanted},
                        strict=True)
    return net


def fpr_at_95_tpr(scores: np.ndarray, labels: np.ndarray) -> float:
    """ood-metrics' ``fpr_at_95_tpr``: FPR linearly interpolated at TPR 0.95 on the ROC."""
    fpr, tpr, _ = roc_curve(labels, scores)
    if np.all(tpr < 0.95):
        return 0.0
    if np.all(tpr >= 0.95):
        return float(fpr[tpr >= 0.95].min())
    return float(np.interp(0.95, tpr, fpr))


def frame_pairs(track: Path, frames: int | None = None):
    """``(image path, label path)`` of a SegmentMeIfYouCan validation folder, in name order."""
    images = sorted((track / "images").iterdir(), key=lambda p: (len(p.stem), p.stem))[:frames]
    return [(image, track / "labels_masks" / f"{image.stem}_labels_semantic.png") for image in images]


def scores_of(logits: np.ndarray) -> dict[str, np.ndarray]:
    """logits (19, H, W) float32 -> each method's (H, W) anomaly score in float64."""
    logits = logits.astype(np.float64)
    shifted = logits - logits.max(0)
    probs = np.exp(shifted) / np.exp(shifted).sum(0)
    return {"msp": 1.0 - probs.max(0), "max_logit": -logits.max(0),
            "entropy": -(probs * np.log(np.maximum(probs, 1e-300))).sum(0)}


def community_metrics(weights: Path, track: Path, frames: int | None = None) -> dict:
    """``{method: {"ap", "fpr95"}}`` (fractions) and ``"counted"`` (frame names) over ``track``."""
    net = erfnet(weights)
    pooled = {name: [] for name in METHODS}
    truths, counted = [], []
    for image_path, label_path in frame_pairs(track, frames):
        label = np.array(Image.open(label_path).resize(SIZE[::-1], Image.NEAREST))
        if not (label == 1).any():
            continue
        image = Image.open(image_path).convert("RGB").resize(SIZE[::-1], Image.BILINEAR)
        tensor = torch.from_numpy(np.array(image)).permute(2, 0, 1)[None].float().div(255)
        with torch.no_grad():
            logits = net(tensor)[0, :19].numpy()
        keep = (label == 0) | (label == 1)
        for name, score in scores_of(logits).items():
            pooled[name].append(score[keep])
        truths.append(label[keep] == 1)
        counted.append(image_path.stem)
    truth = np.concatenate(truths)
    result: dict = {"counted": counted}
    for name in METHODS:
        scores = np.concatenate(pooled[name])
        result[name] = {"ap": float(average_precision_score(truth, scores)), "fpr95": fpr_at_95_tpr(scores, truth)}
    return result


if __name__ == "__main__":
    out = community_metrics(Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) > 3 else None)
    print("frames counted:", " ".join(out["counted"]))
    for method in METHODS:
        print(f"{method}: AP {100 * out[method]['ap']:.4f}  FPR95 {100 * out[method]['fpr95']:.4f}")
