"""CuDAM Table V: the attention module at the deep position (after the first decoder
convolution) against the surface position (just before the classifier), ``DeepLabV3Plus.cudam_position``.

    python -m experiments --only cudam_table5
"""
from experiments.common import Row, cudam, improves

NAME = "cudam_table5"
TITLE = "CuDAM Table V: attention position"


def rows(scale):
    return [Row("surface position", cudam(scale, position="surface"), "sml_post+att"),
            Row("deep position", cudam(scale), "sml_post+att")]


def findings(v):
    return [improves(v, "deep position", "surface position", ("ap", "fpr95", "auroc"),
                     "deep beats surface in AP, FPR95 and AUROC"),
            improves(v, "surface position", "deep position", ("miou",), "surface has slightly higher mIoU")]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
