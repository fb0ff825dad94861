"""How far the community table moves for weights within half an int8 step of the ones we have.

    python -m experiments.real_erfnet_int8_spread [--draws 8]   # writes real_erfnet_int8_spread.json / .md

The ERFNet weights we have are an int8 redistribution (one scale per conv weight tensor) of the
authors' float weights, which are not in reach. Rounding put each float weight within half a step
(``scale / 2``) of the int8 grid, so the float network is one point of the box "grid value +
U(-scale/2, scale/2)". Each draw here takes a random network from that box (draw 0: the grid
itself) and evaluates it with ``--protocol erfnet-community`` on RoadAnomaly21 and RoadObstacle21.
The spread of each number over the draws says how much rounding of this size moves it: a gap
between our int8 numbers and the published float ones that lies within that spread is one the
quantisation can explain. A random draw is about twice as far from the float weights as the grid is
(two roundings' worth of noise), so the spread is an upper estimate.
"""
from __future__ import annotations

import argparse

import numpy as np

from experiments.real_common import HERE, require_realdata
from experiments.real_erfnet_community import LABELS, PUBLISHED, WEIGHTS
from jaxanom.io import write_bytes_atomic, write_json_atomic

NAME = "real_erfnet_int8_spread"
METHODS = ("msp", "max_logit", "entropy")


def quantisation_steps(path) -> dict[str, float]:
    """The scale (one int8 step) of every quantised tensor in the state dict at ``path``."""
    import torch

    state = torch.load(path, weights_only=True, map_location="cpu")
    return {key: float(value.q_scale()) for key, value in state.items()
            if isinstance(value, torch.Tensor) and value.is_quantized}


def draw_weights(state: dict, steps: dict[str, float], seed: int) -> dict:
    """``state`` with every quantised tensor moved by U(-step/2, step/2) per element (seed 0: unchanged)."""
    if seed == 0:
        return state
    rng = np.random.default_rng(seed)
    return {key: (value + rng.uniform(-0.5, 0.5, value.shape) * steps[key]).astype(np.float32)
            if key in steps else value for key, value in state.items()}


def main(draws: int = 8) -> dict:
    from jaxanom.app.evaluate import anomaly_results, dataset_reader, predictor, protocol_predictions
    from jaxanom.protocols import get_protocol
    from jaxanom.weights import from_torch, read_state_dict

    path = require_realdata(*WEIGHTS)
    steps, grid = quantisation_steps(path), read_state_dict(path)
    protocol = get_protocol("erfnet-community")
    results = {"weights": "/".join(WEIGHTS), "quantised_tensors": len(steps), "draws": []}
    for seed in range(draws):
        model, variables = from_torch(draw_weights(grid, steps, seed), "erfnet-cityscapes")
        predict, row = predictor(model, variables), {"seed": seed}
        for track in PUBLISHED:
            source = dataset_reader("smiyc", str(require_realdata(track)))
            metrics, _ = anomaly_results(protocol_predictions(predict, source, protocol), METHODS,
                                         fpr_convention=protocol.fpr_convention,
                                         ap_convention=protocol.ap_convention, drop_void=protocol.drop_void)
            row[track] = {name: {"ap": 100 * metrics[name]["ap"], "fpr95": 100 * metrics[name]["fpr_at_tpr"]}
                          for name in METHODS}
        results["draws"].append(row)
        print(f"draw {seed + 1}/{draws} done", flush=True)
    write_json_atomic(HERE / f"{NAME}.json", results)
    write_bytes_atomic(HERE / f"{NAME}.md", markdown(results).encode())
    return results


def markdown(results: dict) -> str:
    draws = results["draws"]
    lines = ["# ERFNet's community table: how much half an int8 step moves it", "",
             f"Written by `python -m experiments.{NAME}`. {len(draws)} networks: draw 0 is the int8 grid "
             f"(`{results['weights']}`, dequantised); draws 1-{len(draws) - 1} move each of its "
             f"{results['quantised_tensors']} quantised weight tensors by U(-step/2, step/2) per element, the box "
             "in which the authors' float weights lie. Protocol `erfnet-community`; AP / FPR95 in %. 'gap': the "
             "grid's number minus the published float one; 'shift of the draws': the smallest and largest "
             "change from the grid (perturbed minus grid) over the perturbed draws.", ""]
    for track, published in PUBLISHED.items():
        lines += [f"## {track}", "", "| score | grid AP / FPR95 | published | gap AP / FPR95 | shift of the draws: AP "
                  "| shift: FPR95 |", "|---|---|---|---|---|---|"]
        for name in METHODS:
            grid = draws[0][track][name]
            shifts = {key: [d[track][name][key] - grid[key] for d in draws[1:]] for key in ("ap", "fpr95")}
            ap, fpr = published[name]
            span = {key: f"{min(v):+.2f} .. {max(v):+.2f}" if v else "-" for key, v in shifts.items()}
            lines.append(f"| {LABELS[name]} | {grid['ap']:.2f} / {grid['fpr95']:.2f} | {ap:.2f} / {fpr:.2f} | "
                         f"{grid['ap'] - ap:+.2f} / {grid['fpr95'] - fpr:+.2f} | {span['ap']} | {span['fpr95']} |")
        lines.append("")
    inside = [f"{track} {LABELS[name]} {key}" for track, published in PUBLISHED.items() for name in METHODS
              for key, index in (("ap", 0), ("fpr95", 1)) if within_shift(draws, track, name, key, published[name][index])]
    lines += [f"Gaps (grid minus published) within the range of the draws' shifts: {len(inside)} of "
              f"{4 * len(METHODS)}: " + (", ".join(inside) or "none") + ".", ""]
    return "\n".join(lines)


def within_shift(draws: list[dict], track: str, name: str, key: str, published: float) -> bool:
    """Whether the grid's gap (grid minus the published float number) lies within the range of the
    draws' shifts (perturbed minus grid, 0 included): the grid is the float weights moved by one
    rounding, so a gap that rounding-sized moves from the grid reproduce is one rounding explains."""
    grid = draws[0][track][name][key]
    shifts = [d[track][name][key] - grid for d in draws[1:]] + [0.0]
    return len(shifts) > 1 and min(shifts) <= grid - published <= max(shifts)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=8, help="networks evaluated, the grid included (default 8)")
    count = parser.parse_args().draws
    if count < 1:
        parser.error(f"--draws: expected at least 1, got {count}")
    print(markdown(main(count)))
