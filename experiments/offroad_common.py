"""What the off-road experiments (the off-road paper: ``offroad_exp2``, ``offroad_table2``, ``offroad_table3``) share.

Sizes: the runner's ``Scale`` describes segmentation networks; the off-road experiments use only
its ``seed`` and whether it is a smoke run (``Scale.smoke()``'s handful of training steps), and
take their sizes from ``jaxanom demo offroad`` (``OffroadDemoConfig``: 128 x 256 frames, the tiny
patch encoder for 150 steps, 24 annotated frames of domain A with 12 patches each), with the BIC
scan widened to the paper-scale m = 2..12 (docs/papers/offroad.md#unstated-settings). A smoke run uses ``OffroadDemoConfig.quick()``.

Sharing: the model learned on domain A (M_A) for a granularity and seed is trained once per
process (``model_on_a``) and reused by every experiment and row that starts from it; each
experiment caches its per-seed values in ``<runs>/offroad/<name>_<hash of sizes>.json``, so a rerun
(or an interrupted run) recomputes only what is missing. Delete that folder after changing the code.

Tables give the mean and sample std (ddof 1) over seeds. Rows that keep per-frame values (``PER_FRAME``:
each frame's FLR, each frame's confusion matrix) are compared paired: one hierarchical bootstrap over
seeds and frames (``experiments.stats``) resamples every row, and a finding holds only when the 95%
interval of the paired difference lies on the paper's side of 0. A comparison whose metric is the same
in every replicate (e.g. scene coverage at 100% in every frame of both rows) cannot separate the rows:
its finding is untested. Rows without per-frame values (Exp. 2's cluster counts) fall back to the
difference of means against the larger std of the rows compared.
"""
from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
import time
from pathlib import Path
from typing import Callable, Sequence

import jax

import numpy as np

from experiments import common
from experiments.common import Finding, Scale, _cell, _delta, _row_json, _tested, aggregate, control_lines, seed_scales
from experiments.jobs import Job
from experiments.stats import hierarchical, hierarchical_draws
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.app.offroad_experiment import OffroadDemoConfig, annotated, source_frames
from jaxanom.offroad.encoder import AnnotatedFrames
from jaxanom.app.offroad_pipeline import OffroadModel, learn


@dataclasses.dataclass(frozen=True)
class OffroadSizes:
    """Sizes of the off-road experiments.

    ``demo``: frames, encoder, BIC scan, training frames of A and the seed (of the synthetic
    worlds, the annotator and the keys). ``active_frames`` / ``test_frames``: frames of the
    sequences B / C. ``budgets``: the hard-frame budgets of Table 2 (``compared_budget`` is the one
    where Rand / Unif / active are compared); ``gap``: Eq. 16's Delta. ``deepscene_frames``: frames
    of D; ``deepscene_budgets``: the budgets standing for the paper's D20 and D40;
    ``deepscene_test``: segmented frames of E, ``deepscene_test_step`` apart. ``segmented``: frames
    of B and of C (evenly spaced) scored by PA / mIoU in Table 2.
    """

    demo: OffroadDemoConfig
    active_frames: int = 48
    test_frames: int = 32
    budgets: tuple[int, ...] = (2, 4, 8)
    compared_budget: int = 4
    gap: int = 3
    deepscene_frames: int = 40
    deepscene_budgets: tuple[int, int] = (4, 8)
    deepscene_test: int = 4
    deepscene_test_step: int = 8
    segmented: int = 4

    @property
    def smoke(self) -> bool:
        return self.demo.pipeline.encoder.steps < 10


def is_smoke(scale: Scale) -> bool:
    """A smoke run: the runner's ``--smoke`` (``Scale.smoke()``: at most its handful of training steps)."""
    return scale.steps <= Scale.smoke().steps


def offroad_sizes(scale: Scale) -> OffroadSizes:
    """The experiments' sizes for ``scale``'s seed (the demo's; tiny for a smoke run)."""
    if is_smoke(scale):
        quick = OffroadDemoConfig.quick()
        demo = dataclasses.replace(quick, seed=scale.seed, pipeline=dataclasses.replace(quick.pipeline, gap=1))
        return OffroadSizes(demo, active_frames=5, test_frames=3, budgets=(1, 2), compared_budget=2, gap=1,
                            deepscene_frames=4, deepscene_budgets=(1, 2), deepscene_test=1, deepscene_test_step=1, segmented=1)
    base = OffroadDemoConfig()
    pipeline = dataclasses.replace(base.pipeline, components=tuple(range(2, 13)), gap=OffroadSizes.gap)
    return OffroadSizes(dataclasses.replace(base, pipeline=pipeline, seed=scale.seed))


_MODELS: dict[OffroadDemoConfig, tuple[OffroadModel, AnnotatedFrames]] = {}


def model_on_a(config: OffroadDemoConfig, log: Callable = print) -> tuple[OffroadModel, AnnotatedFrames]:
    """``(M_A, its annotations)``: S1 on ``config.train`` annotated at ``config.granularity``, with the
    demo's key (so it is the demo's M_A for the same config); trained once per config in this process."""
    if config not in _MODELS:
        start = time.perf_counter()
        frames = [f for source in config.train for f in source_frames(source, config)]
        data = annotated(frames, config, 0)
        model = learn(jax.random.fold_in(jax.random.key(config.seed), 1), data, config.pipeline)
        log(f"  M_A ({config.granularity}, seed {config.seed}): m = {model.num_clusters}, "
            f"learned in {time.perf_counter() - start:.0f} s")
        _MODELS[config] = (model, data)
    return _MODELS[config]


def cache_path(name: str, sizes: OffroadSizes, runs: Path) -> Path:
    """``<runs>/offroad/<name>_<hash of sizes>.json``: one seed's values of one experiment."""
    text = json.dumps(dataclasses.asdict(sizes), sort_keys=True, default=str)
    return Path(runs) / "offroad" / f"{name}_{hashlib.sha256(text.encode()).hexdigest()[:12]}.json"


def per_seed(name: str, sizes: OffroadSizes, runs: Path, compute: Callable[[], dict], log: Callable = print) -> dict:
    """``compute()`` (the values ``{row: {metric: value, ...}}`` of one seed), cached in ``cache_path`` with
    the seconds it took."""
    path = cache_path(name, sizes, runs)
    if path.exists():
        log(f"  {name} seed {sizes.demo.seed}: cached in {path}")
        return dict(json.loads(path.read_text())["rows"])
    start = time.perf_counter()
    values = compute()
    seconds = time.perf_counter() - start
    log(f"  {name} seed {sizes.demo.seed}: {seconds:.0f} s")
    write_json_atomic(path, {"rows": list(values.items()), "seconds": seconds})  # a list keeps the rows' order
    return values


def seed_minutes(name: str, sizes: Sequence[OffroadSizes], runs: Path) -> float | None:
    """Minutes that computing these seeds took (their caches' ``seconds``); None where a cache lacks them."""
    seconds = [json.loads(cache_path(name, z, runs).read_text()).get("seconds") for z in sizes]
    return None if None in seconds else sum(seconds) / 60


def compute_seed(names: Sequence[str], sizes: OffroadSizes, runs: Path) -> None:
    """One seed's values of the off-road experiments ``names``, in order and into their caches (``per_seed``),
    sharing this process's M_A (a ``jobs.Job``)."""
    for name in names:
        module = importlib.import_module(f"experiments.{name}")
        per_seed(name, sizes, runs, lambda: module.seed_values(sizes, print))


def seed_jobs(names: Sequence[str], scale: Scale, seeds: int, runs: Path) -> list[Job]:
    """``compute_seed`` of every seed that some experiment of ``names`` has not cached."""
    sizes = [offroad_sizes(s) for s in seed_scales(scale, seeds)]
    return [Job(f"off-road seed {z.demo.seed}", compute_seed, (tuple(names), z, runs), 13.0) for z in sizes
            if names and not all(cache_path(name, z, runs).exists() for name in names)]


PER_FRAME = "per_frame"  # a row's per-frame values in a seed's cache: {kind: (F, ...) nested lists}


def paired_replicates(seed_frames: Sequence[dict], metrics: dict[str, Callable]) -> dict:
    """``{label: {metric: (R,)}}``: one set of ``hierarchical_draws`` (seeds, then each seed's frames of every
    kind) shared by every row. ``seed_frames[s][label][kind]``: (F, ...) per-frame counts of seed s, the same F
    for every row; ``metrics[kind](label)(pooled (n, ...)) -> {metric: (n,)}``: the metric of a row."""
    labels = list(seed_frames[0])
    counts = {kind: [len(seed[labels[0]][kind]) for seed in seed_frames] for kind in metrics}
    for label in labels:
        got = {kind: [len(seed[label][kind]) for seed in seed_frames] for kind in metrics}
        if got != counts:
            raise ValueError(f"seed_frames: row {label!r} has frames {got}, the first row {counts}")
    draws = hierarchical_draws(counts)
    return {label: {name: values for kind, metric in metrics.items()
                    for name, values in hierarchical([np.asarray(seed[label][kind], np.float64) for seed in seed_frames],
                                                     draws, kind, metric(label)).items()}
            for label in labels}


def comparison(values: dict, a: str, b: str, metric: str, lower: bool = False) -> dict:
    """``experiments.common.comparison`` (``lower``: lower is better) with ``separable``: False where both
    rows are paired and their replicates are equal in every replicate (nothing can separate them)."""
    c = common.comparison(values, a, b, metric, lower)
    paired = c["low"] is not None
    return {**c, "separable": not paired or not np.array_equal(values[a]["replicates"][metric],
                                                               values[b]["replicates"][metric], equal_nan=True)}


def _pair_text(values: dict, c: dict, name: str) -> str:
    text = f"{name} {_cell(values[c['a']], c['metric'])} vs {_cell(values[c['b']], c['metric'])}"
    return text if c["low"] is None else f"{text}, {_delta(c)}"


def _finding(claim: str, holds: bool, evidence: str, comparisons: Sequence[dict], names: dict[str, str]) -> Finding:
    """A finding with its rows and comparisons; untested where a comparison cannot separate its rows.
    ``names``: metric -> the name the evidence gives it."""
    rows = list(dict.fromkeys(x for c in comparisons for x in (c["a"], c["b"])))
    same = [f"{c['a']} and {c['b']} have the same {names[c['metric']]} in every bootstrap replicate"
            for c in comparisons if not c["separable"]]
    intervals = [{k: v for k, v in c.items() if k != "separable"} for c in comparisons if c["low"] is not None]
    return Finding(claim, holds, evidence, rows, intervals, False if same else None,
                   "; ".join(same) + " (the metric is saturated here)" if same else "")


def beats(values: dict, a: str, b: str, metrics: dict[str, str], claim: str, lower: Sequence[str] = ()) -> Finding:
    """``a`` beats ``b`` in every metric of ``metrics`` (metric -> its name); ``lower``: lower is better."""
    compared = [comparison(values, a, b, m, m in lower) for m in metrics]
    return _finding(claim, all(c["better"] for c in compared),
                    ", ".join(_pair_text(values, c, metrics[c["metric"]]) for c in compared), compared, metrics)


def not_beaten(values: dict, a: str, b: str, metrics: dict[str, str], claim: str, lower: Sequence[str] = ()) -> Finding:
    """``a`` is at ``b``'s level: ``b`` beats ``a`` in none of ``metrics``."""
    compared = [comparison(values, b, a, m, m in lower) for m in metrics]
    evidence = ", ".join(_pair_text(values, comparison(values, a, b, m, m in lower), name)
                         for m, name in metrics.items())
    return _finding(claim, not any(c["better"] for c in compared), evidence, compared, metrics)


def chain(values: dict, rows: Sequence[str], metric: str, name: str, claim: str, lower: bool = False) -> Finding:
    """Each row of ``rows`` beats the one before it in ``metric``."""
    compared = [comparison(values, b, a, metric, lower) for a, b in zip(rows, rows[1:])]
    evidence = f"{name}: " + ", ".join(f"{r} {_cell(values[r], metric)}" for r in rows)
    if all(c["low"] is not None for c in compared):
        evidence += "; " + ", ".join(f"{c['a']} − {c['b']} {_delta(c)}" for c in compared)
    return _finding(claim, all(c["better"] for c in compared), evidence, compared, {metric: name})


def markdown_table(values: dict, columns: dict[str, str]) -> str:
    """Rows of ``values`` (from ``aggregate``) with the ``columns`` (metric -> header), mean ± std."""
    lines = ["| row | " + " | ".join(columns.values()) + " |", "|---" * (len(columns) + 1) + "|"]
    lines += [f"| {label} | " + " | ".join(_cell(v, m) for m in columns) + " |" for label, v in values.items()]
    return "\n".join(lines)


def run_seeds(name: str, title: str, description: str, scale: Scale, seeds: int, out_dir: Path, runs: Path,
              seed_values: Callable[[OffroadSizes, Callable], dict], columns: dict[str, str],
              findings: Callable[[dict], list[Finding]], log: Callable = print,
              controls: Callable[[dict], list[Finding]] | None = None,
              paired: dict[str, Callable] | None = None) -> dict:
    """Every seed's values (``seed_values(sizes, log)``, cached), aggregated; with ``paired`` (kind -> row label
    -> metric of pooled per-frame counts, ``paired_replicates``) every row's replicates attached from its ``PER_FRAME``
    values; the findings and the positive ``controls`` checked; ``<name>.json`` and ``<name>.md`` written to
    ``out_dir``. Returns the result."""
    log(f"{name}: {title}")
    scales = seed_scales(scale, seeds)
    sizes = [offroad_sizes(s) for s in scales]
    cached = [per_seed(name, z, runs, lambda z=z: seed_values(z, log), log) for z in sizes]
    frames = [{label: row.pop(PER_FRAME) for label, row in seed.items() if PER_FRAME in row} for seed in cached]
    values = aggregate(cached, tuple(columns))
    if paired:
        for label, replicates in paired_replicates(frames, paired).items():
            values[label]["replicates"] = replicates
    checked = findings(values)
    rule = ("rows are compared paired: one hierarchical bootstrap over seeds and frames resamples every row, and a "
            "finding holds only when the 95% interval of the paired difference excludes 0 on the paper's side"
            if paired else "a finding holds only when the difference of means exceeds the larger std of the rows it "
            "compares")
    seed_text = (f"{len(scales)} seed(s) ({', '.join(str(s.seed) for s in scales)}), each setting the synthetic worlds, "
                 "the simulated annotator and the encoder's initialisation and batches; values are mean ± sample std "
                 f"(ddof 1) over seeds; {rule}")
    minutes = seed_minutes(name, sizes, runs)
    timing = f" Run time: {minutes:.1f} min to compute its seeds (their caches' record)." if minutes else ""
    lines = [f"## {title}", "", description + timing, "", markdown_table(values, columns), "", f"`{name}`; {seed_text}.",
             "", "| paper's finding | holds here? | tested? | evidence |", "|---|---|---|---|"]
    lines += [f"| {f.claim} | {'yes' if f.holds else '**no**'} | {_tested(dataclasses.asdict(f))} | {f.evidence} |"
              for f in checked]
    checked_controls = [dataclasses.asdict(f) for f in (controls(values) if controls else [])]
    report = "\n".join(lines + control_lines(checked_controls))
    result = {"name": name, "title": title, "description": description,
              "table": [_row_json(k, v) for k, v in values.items()],
              "scale": dataclasses.asdict(scales[0]),
              "sizes": json.loads(json.dumps(dataclasses.asdict(sizes[0]), default=str)),
              "findings": [dataclasses.asdict(f) for f in checked], "controls": checked_controls, "seeds": seed_text,
              "num_seeds": len(scales), "paired": bool(paired), "report": report}
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / f"{name}.json", result)
    write_bytes_atomic(out_dir / f"{name}.md", (report + "\n").encode())
    return result
