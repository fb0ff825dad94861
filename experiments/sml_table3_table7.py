"""SML Tables 3 and 7: max logit -> SML -> + boundary suppression / + dilated smoothing / + both,
and the same post-processing applied to MSP and max logit. One plain network (no attention).
Positive control: the same trained network with each pixel's logits multiplied by a factor of its
predicted class, from 1/4 to 4 over the classes (``scaled_logits``), where SML (Eq. 5, its
statistics fitted on those logits) must beat max logit.

    python -m experiments --only sml_table3_table7
"""
from experiments.common import Row, best, improves, logit_scale_control, logit_scale_rows, not_better, ordered, plain, worse

NAME = "sml_table3_table7"
TITLE = "SML Table 3 (components) and Table 7 (post-processing on other scores)"
BOTH = " + suppression + smoothing"


def rows(scale):
    net = plain(scale)
    return [Row("MSP", net, "msp"), Row("MSP" + BOTH, net, "msp_post"),
            Row("max logit", net, "max_logit"), Row("max logit" + BOTH, net, "max_logit_post"),
            Row("SML", net, "sml"), Row("SML + suppression", net, "sml_suppress"),
            Row("SML + smoothing", net, "sml_smooth"), Row("SML" + BOTH, net, "sml_post"), *logit_scale_rows(net)]


def findings(v):
    sml_rows = ["SML", "SML + suppression", "SML + smoothing", "SML" + BOTH]
    return [
        ordered(v, ["MSP", "max logit", "SML"], "ap", "Table 7: AP of MSP < max logit < SML"),
        improves(v, "SML", "max logit", ("ap", "fpr95"), "Table 3: SML beats max logit (AP up, FPR95 down)"),
        improves(v, "SML + suppression", "SML", ("ap", "fpr95"), "Table 3: suppression improves SML (AP up, FPR95 down)"),
        improves(v, "SML + smoothing", "SML", ("ap",), "Table 3: smoothing alone raises AP"),
        worse(v, "SML + smoothing", "SML", "fpr95", "Table 3: smoothing alone raises FPR95 slightly"),
        best(v, "SML" + BOTH, sml_rows, "ap", "Table 3: suppression + smoothing gives SML's best AP"),
        best(v, "SML" + BOTH, sml_rows, "fpr95", "Table 3: suppression + smoothing gives SML's best FPR95"),
        not_better(v, "MSP" + BOTH, "MSP", "ap", "Table 7: post-processing does not improve MSP's AP"),
        not_better(v, "max logit" + BOTH, "max logit", "ap", "Table 7: post-processing does not improve max logit's AP"),
        improves(v, "SML" + BOTH, "SML", ("ap", "fpr95", "auroc"), "Table 7: post-processing improves SML in every metric"),
    ]


def controls(v):
    return [logit_scale_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
