"""Results tables and pictures shared by the demos and the commands that score a dataset."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxanom import method_registry
from jaxanom.app.outputs import within


def results_table(metrics: dict, segmentation: dict | None = None) -> str:
    """A markdown table of AP / AUROC / FPR@95 per method (percent), with SegmentMeIfYouCan's
    component metrics (mean sIoU, mean PPV, mean F1) where ``metrics`` hold them."""
    components = all("components" in m for m in metrics.values())
    extra = " sIoU | PPV | mean F1 |" if components else ""
    lines = ["| method | AP | AUROC | FPR@95 |" + extra, "|---|---|---|---|" + "---|" * (3 * components)]
    percent = lambda x: "n/a" if x is None else f"{100 * x:.2f}"  # noqa: E731
    for name, m in metrics.items():
        row = f"| {name} | {100 * m['ap']:.2f} | {100 * m['auroc']:.2f} | {100 * m['fpr_at_tpr']:.2f} |"
        if components:
            c = m["components"]
            row += f" {percent(c['mean_siou'])} | {percent(c['mean_ppv'])} | {percent(c['f1_mean'])} |"
        lines.append(row)
    if segmentation is not None:
        lines.append(f"\nsegmentation mIoU on in-distribution frames: {100 * segmentation['miou']:.2f}")
    return "\n".join(lines)


def evaluators_lines(metrics: dict) -> str:
    """One line ``METHOD NAME: {its metrics}`` per named evaluator of each method
    (``metrics[method]["evaluators"][name]``), in order."""
    return "\n".join(f"{method} {name}: {values}" for method, m in metrics.items()
                     for name, values in m.get("evaluators", {}).items())


def conventions_table(metrics: dict) -> str:
    """A markdown table of AP and FPR@95 (percent) per method under every convention the library
    has on the exact curve (``metrics[name]["ap_conventions"]`` / ``["fpr_conventions"]``, in
    ``["exact"]`` where the kit's numbers replaced them), side by side."""
    from jaxanom.metrics.anomaly import AP_CONVENTIONS, FPR_CONVENTIONS

    header = [f"AP {c}" for c in AP_CONVENTIONS] + [f"FPR@95 {c}" for c in FPR_CONVENTIONS]
    lines = ["| method (exact curve) | " + " | ".join(header) + " |", "|---|" + "---|" * len(header)]
    for name, m in metrics.items():
        m = m.get("exact", m)
        values = [m["ap_conventions"][c] for c in AP_CONVENTIONS] + [m["fpr_conventions"][c] for c in FPR_CONVENTIONS]
        lines.append(f"| {name} | " + " | ".join(f"{100 * v:.2f}" for v in values) + " |")
    return "\n".join(lines)


def write_pictures(out_dir: Path, predict, source, stats, count: int, data: str = "cityscapes") -> None:
    """``frame_<i>.png`` for the first ``count`` frames of ``source``: image | prediction |
    anomaly label | SML + post-processing score (MSP without ``stats``) | CuDAM attention (with an
    attention model); titled, with class legends and colour bars. ``data``: the data the network
    was trained on ("camvid": CamVid's classes, otherwise Cityscapes')."""
    from jaxanom.data import camvid, cityscapes_labels
    from jaxanom.viz import Panel, anomaly_label_panel, label_panel, write_panels

    classes = camvid if data == "camvid" else cityscapes_labels

    for index in range(min(count, len(source))):
        frame = source[index]
        out = predict(frame["image"][None])
        score = method_registry.score("sml_post" if stats else "msp", {"logits": out["logits"], "stats": stats})[0]
        panels = [Panel("image", frame["image"]),
                  label_panel("prediction", np.asarray(out["logits"][0].argmax(-1)), classes.CLASS_NAMES,
                              classes.CLASS_COLORS),
                  anomaly_label_panel(frame["label"]),
                  Panel("score: SML + post-processing" if stats else "score: MSP", np.asarray(score),
                        label="anomaly score")]
        if "attention_up" in out:
            panels.append(Panel("CuDAM attention (Eq. 1)", np.asarray(out["attention_up"][0]), cmap="viridis",
                                label="attention"))
        write_panels(within(out_dir, out_dir / f"frame_{index}.png"), panels)
