"""MSAAM Table 6: MSP, max logit, entropy and SML on the plain network and on the network with MSAAM at
the end of the encoder (trained with MSAAM's loss, Eq. 7). Positive control: SML's
(``logit_scale_rows``) on the MSAAM network, since no row can be built so that MSAAM's features must
help; it checks that this network's scores are computed and normalised right.

    python -m experiments --only msaam_table6
"""
from experiments.common import Row, improves, logit_scale_control, logit_scale_rows, msaam, plain

NAME = "msaam_table6"
TITLE = "MSAAM Table 6: gains of MSAAM on scores without extra training"
SCORES = {"MSP": "msp", "max logit": "max_logit", "entropy": "entropy", "SML": "sml_post"}


def rows(scale):
    base, ours = plain(scale), msaam(scale)
    return [*(Row(label, base, score) for label, score in SCORES.items()),
            *(Row(f"MSAAM + {label}", ours, score) for label, score in SCORES.items()),
            *logit_scale_rows(ours)]


def findings(v):
    return [improves(v, f"MSAAM + {label}", label, ("ap", "fpr95", "auroc"),
                     f"MSAAM improves {label} in AP, FPR95 and AUROC") for label in SCORES]


def controls(v):
    return [logit_scale_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
