"""CuDAM Fig. 6: the reward weight tau, scored with SML + attention.

The paper's tau = 5e4 is for 180 x 180 attention maps; ``matched_tau`` rescales it to this run's map
size (see ``experiments.common``). The sweep: no reward (tau = 0, trained as ``reward_prob=0``:
identical to tau = 0 since the reward adds tau * M_att), a tenth of the matched value, the matched
value, and the paper's literal 5e4. Positive control: Eq. 10 with an attention map on the anomalies
only (``oracle_attention``) must beat SML of the same CuDAM network.

    python -m experiments --only cudam_fig6
"""
from experiments.common import PAPER_TAU, Row, best, cudam, improves, matched_tau, oracle_control, oracle_rows, worse

NAME = "cudam_fig6"
TITLE = "CuDAM Fig. 6: reward weight tau"


def rows(scale):
    tau = matched_tau(scale)
    return [Row("tau = 0 (no reward)", cudam(scale, reward_prob=0.0), "sml_post+att"),
            Row(f"tau = {tau / 10:.4g} (matched / 10)", cudam(scale, tau=tau / 10), "sml_post+att"),
            Row(f"tau = {tau:.4g} (matched: the paper's 5e4 rescaled)", cudam(scale, tau=tau), "sml_post+att"),
            Row("tau = 5e4 (the paper's literal value)", cudam(scale, tau=PAPER_TAU), "sml_post+att"),
            *oracle_rows(cudam(scale))]


def findings(v):
    labels = [label for label in v if not label.startswith("control:")]  # the sweep, in the order of rows()
    none, _, matched, literal = labels
    return [best(v, matched, labels, "ap", "AP peaks at the paper's tau (rescaled)"),
            improves(v, matched, none, ("ap",), "the reward at the paper's tau beats no reward"),
            worse(v, literal, matched, "ap", "a much larger tau lowers AP")]


def controls(v):
    return [oracle_control(v)]


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
