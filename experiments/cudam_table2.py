"""CuDAM Table II: MSP, max logit and SML without CuDAM (plain network) and with it (the CuDAM-trained
network, score + sigma * attention, Eq. 10). Positive control: Eq. 10 with an attention map on the
anomalies only (``oracle_attention``) must beat SML of the same CuDAM network.

    python -m experiments --only cudam_table2
"""
from experiments.common import Row, cudam, improves, oracle_control, oracle_rows, ordered, plain

NAME = "cudam_table2"
TITLE = "CuDAM Table II: uncertainty scores with and without CuDAM"


def rows(scale):
    base, ours = plain(scale), cudam(scale)
    return [Row("MSP", base, "msp"), Row("max logit", base, "max_logit"), Row("SML", base, "sml_post"),
            Row("CuDAM + MSP", ours, "msp+att"), Row("CuDAM + max logit", ours, "max_logit+att"),
            Row("CuDAM + SML", ours, "sml_post+att"),
            Row("CuDAM + SML (paper's sigma 2e4)", ours, "cudam"),
            Row("CuDAM network, SML without attention term", ours, "sml_post"),
            *oracle_rows(ours)]


def findings(v):
    metrics = ("ap", "fpr95", "auroc")
    return [
        *(improves(v, f"CuDAM + {s}", s, metrics, f"CuDAM improves {s} in AP, FPR95 and AUROC")
          for s in ("MSP", "max logit", "SML")),
        ordered(v, ["MSP", "max logit", "SML"], "ap", "without CuDAM, AP: MSP < max logit < SML"),
        ordered(v, ["CuDAM + MSP", "CuDAM + max logit", "CuDAM + SML"], "ap", "with CuDAM, AP: MSP < max logit < SML"),
        improves(v, "CuDAM + SML", "SML", ("miou",), "CuDAM raises mIoU slightly"),
    ]


def controls(v):
    return [oracle_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
