"""CuDAM Fig. 5: reward probability 0.3 / 0.5 / 0.7 (probability of a study iteration), scored with SML
+ attention; "no reward" (probability 0) for reference. Positive control: Eq. 10 with an attention
map on the anomalies only (``oracle_attention``) must beat SML of the same CuDAM network.

    python -m experiments --only cudam_fig5
"""
from experiments.common import Row, best, cudam, improves, oracle_control, oracle_rows

NAME = "cudam_fig5"
TITLE = "CuDAM Fig. 5: reward probability"
PROBABILITIES = (0.3, 0.5, 0.7)


def rows(scale):
    return [Row("p = 0 (no reward)", cudam(scale, reward_prob=0.0), "sml_post+att"),
            *(Row(f"p = {p}", cudam(scale, reward_prob=p), "sml_post+att") for p in PROBABILITIES),
            *oracle_rows(cudam(scale))]


def findings(v):
    swept = [f"p = {p}" for p in PROBABILITIES]
    return [improves(v, "p = 0.3", "p = 0 (no reward)", ("ap",), "p = 0.3 already improves on no reward"),
            best(v, "p = 0.5", swept, "ap", "p = 0.5 gives the best AP"),
            best(v, "p = 0.5", swept, "fpr95", "p = 0.5 gives the lowest FPR95")]


def controls(v):
    return [oracle_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
