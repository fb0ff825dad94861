"""Off-road Exp. 2 (seed 001, Fig. 10a): the cluster count chosen by BIC against the granularity of the
patch annotations. For each granularity (LV1: 4 classes, LV2: 6, LV3: 10 in the synthetic hierarchy;
the paper's private data has 4 / 6 / 9) the patch encoder is trained from scratch on the same 24
frames of domain A annotated at that granularity (12 patches per frame), and the GMM's m is chosen
by the decisive BIC minimum over m = 2..12 (D-B4; the argmin of the curve where no minimum is
decisive). "argmin m" is the plain argmin of the same curve; "classes recovered" counts the distinct
reference classes that are the majority of some cluster (D-B13).

    python -m experiments --only offroad_exp2
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from experiments.common import HERE, RUNS, Finding, Scale
from experiments.offroad_common import OffroadSizes, chain, model_on_a, run_seeds
from jaxanom.data.offroad import GRANULARITIES

NAME = "offroad_exp2"
TITLE = "Off-road Exp. 2: clusters found by BIC vs label granularity"
LEVELS = ("lv1", "lv2", "lv3")
COLUMNS = {"classes": "annotated classes", "clusters": "BIC-chosen m", "argmin": "argmin m",
           "recovered": "classes recovered"}


def seed_values(sizes: OffroadSizes, log: Callable = print) -> dict:
    """One seed: ``{"LV1": {classes, clusters, argmin, recovered, network}, ...}``."""
    values = {}
    for level in LEVELS:
        model, _ = model_on_a(dataclasses.replace(sizes.demo, granularity=level), log)
        counts = sorted(model.bics)
        values[level.upper()] = {
            "classes": len(GRANULARITIES[level][0]), "clusters": model.num_clusters,
            "argmin": counts[int(np.argmin([model.bics[m] for m in counts]))],
            "recovered": len(set(model.cluster_class[model.cluster_class >= 0].tolist())),
            "network": f"M_A {level} seed {sizes.demo.seed}", "bics": {str(m): model.bics[m] for m in counts}}
    return values


def findings(v: dict) -> list[Finding]:
    out = [chain(v, [g.upper() for g in LEVELS], "clusters", "m",
                 "the BIC-chosen cluster count rises with the granularity: LV1 < LV2 < LV3 (paper: 4 < 6 < 9)")]
    for level in LEVELS:
        row = v[level.upper()]
        gap = abs(row["clusters"] - row["classes"])
        out.append(Finding(f"{level.upper()}: the BIC-chosen m matches the {int(row['classes'])} annotated classes "
                           "(|mean m - classes| <= 1, or within the std)",
                           gap <= max(1.0, row["clusters_std"]),
                           f"m {row['clusters']:.2f} ± {row['clusters_std']:.2f} (per seed "
                           f"{[int(x) for x in row['clusters_seeds']]}) for {int(row['classes'])} classes"))
    return out


def run(scale: Scale, seeds: int, out_dir: Path = HERE, runs: Path = RUNS, log: Callable = print,
        description: str = "") -> dict:
    """Every seed, aggregated; writes ``offroad_exp2.json/.md``."""
    return run_seeds(NAME, TITLE, description, scale, seeds, out_dir, runs, seed_values, COLUMNS, findings, log)


if __name__ == "__main__":
    from experiments.__main__ import main

    raise SystemExit(main(["--only", NAME]))
