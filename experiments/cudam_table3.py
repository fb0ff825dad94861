"""CuDAM Table III: ablation of the attention module, the reward (Eq. 4) and the attention loss (Eq.
7), scored with SML + attention (Eq. 10).

The CuDAM objective's fields that switch the components off: "no reward" is ``reward_prob=0`` (no
study iteration ever); "no L_att" is ``beta=0`` (the threshold beta * psi is 0 and attention is
positive, so no pixel is penalised and the loss is exactly 0); "attention" alone is both: the CuDAM
network trained with exactly the plain cross-entropy. Two rows of ours: L_att's k from running SML
statistics (``attention_k="running_sml"``, the paper's K) instead of 1 - MSP, and the scale-free gate. Positive
control: Eq. 10 with an attention map on the anomalies only (``oracle_attention``) must beat SML of
the same CuDAM network.

    python -m experiments --only cudam_table3
"""
from experiments.common import Row, best, cudam, improves, oracle_control, oracle_rows, plain, worse

NAME = "cudam_table3"
TITLE = "CuDAM Table III: attention / reward / attention-loss ablation"


def rows(scale):
    return [Row("none (plain network, SML)", plain(scale), "sml_post"),
            Row("attention", cudam(scale, reward_prob=0.0, beta=0.0), "sml_post+att"),
            Row("attention + reward", cudam(scale, beta=0.0), "sml_post+att"),
            Row("attention + L_att", cudam(scale, reward_prob=0.0), "sml_post+att"),
            Row("attention + reward + L_att", cudam(scale), "sml_post+att"),
            Row("attention + reward + L_att, k = running SML", cudam(scale, attention_k="running_sml"),
                "sml_post+att"),
            Row("attention + reward + L_att, scale-free gate", cudam(scale, gate="scale_free"), "sml_post+att"),
            *oracle_rows(cudam(scale))]


def findings(v):
    none = "none (plain network, SML)"
    ablations = ["attention", "attention + reward", "attention + L_att", "attention + reward + L_att"]
    return [
        *(improves(v, a, none, ("ap",), f"{a} improves AP over no CuDAM") for a in ablations),
        improves(v, "attention + reward", "attention + L_att", ("ap",),
                 "the reward helps more than L_att (largest single gain)"),
        best(v, "attention + reward + L_att", [none, *ablations], "ap", "all three components give the best AP"),
        best(v, "attention + reward + L_att", [none, *ablations], "fpr95", "all three components give the best FPR95"),
        worse(v, "attention + L_att", "attention", "miou", "L_att lowers mIoU relative to attention alone"),
        improves(v, "attention + reward + L_att, k = running SML", "attention + reward + L_att", ("ap",),
                 "(ours) k = running SML (the paper's K) improves AP over k = 1 - MSP"),
        improves(v, "attention + reward + L_att, scale-free gate", "attention + reward + L_att", ("ap",),
                 "(ours) the scale-free gate improves AP over Eq. 3 as printed"),
    ]


def controls(v):
    return [oracle_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
