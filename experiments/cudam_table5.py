"""CuDAM Table V: the attention module at the deep position (after the first decoder convolution)
against the paper's surface position (on the output logits at input size,
``cudam_position="output"``); also the scale-free gate (Eq. 3 with h*w*M_att, a deviation) at the
deep position. (Our earlier pre-classifier reading, ``cudam_position="surface"``, is no longer a
row: no claim compared it, and its 3 networks cost 8 minutes of the whole run.) Positive control:
Eq. 10 with an attention map on the anomalies only (``oracle_attention``) must beat SML of the same
CuDAM network.

    python -m experiments --only cudam_table5
"""
from experiments.common import Row, cudam, improves, oracle_control, oracle_rows

NAME = "cudam_table5"
TITLE = "CuDAM Table V: attention position"


def rows(scale):
    return [Row("surface position (paper: output logits)", cudam(scale, position="output"), "sml_post+att"),
            Row("deep position", cudam(scale), "sml_post+att"),
            Row("deep position, scale-free gate", cudam(scale, gate="scale_free"), "sml_post+att"),
            *oracle_rows(cudam(scale))]


def findings(v):
    surface, deep = "surface position (paper: output logits)", "deep position"
    return [improves(v, deep, surface, ("ap", "fpr95", "auroc"), "deep beats surface in AP, FPR95 and AUROC"),
            improves(v, surface, deep, ("miou",), "surface has slightly higher mIoU"),
            improves(v, "deep position, scale-free gate", deep, ("ap",),
                     "(ours) the scale-free gate improves AP over Eq. 3 as printed")]


def controls(v):
    return [oracle_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
