"""What the off-road experiments (seed 001: ``offroad_exp2``, ``offroad_table2``, ``offroad_table3``) share.

Sizes: the runner's ``Scale`` describes segmentation networks; the off-road experiments use only
its ``seed`` and whether it is a smoke run (``Scale.smoke()``'s handful of training steps), and
take their sizes from ``jaxanom demo offroad`` (``OffroadDemoConfig``: 128 x 256 frames, the tiny
patch encoder for 150 steps, 24 annotated frames of domain A with 12 patches each), with the BIC
scan widened to OFFROAD.md's m = 2..12. A smoke run uses ``OffroadDemoConfig.quick()``.

Sharing: the model learned on domain A (M_A) for a granularity and seed is trained once per
process (``model_on_a``) and reused by every experiment and row that starts from it; each
experiment caches its per-seed values in ``<runs>/offroad/<name>_<hash of sizes>.json``, so a rerun
(or an interrupted run) recomputes only what is missing. Delete that folder after changing the code.

Tables give the mean and sample std (ddof 1) over seeds; a finding holds only when the difference
of means exceeds the larger std of the rows compared (the rule of ``experiments.common``).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Callable, Sequence

import jax

from experiments.common import Finding, Scale, _cell, aggregate, control_lines, seed_scales
from jaxanom.io import write_bytes_atomic, write_json_atomic
from jaxanom.app.demos.offroad import OffroadDemoConfig, annotated, source_frames
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


def per_seed(name: str, sizes: OffroadSizes, runs: Path, compute: Callable[[], dict], log: Callable = print) -> dict:
    """``compute()`` (the values ``{row: {metric: value, ...}}`` of one seed), cached in
    ``<runs>/offroad/<name>_<hash of sizes>.json``."""
    text = json.dumps(dataclasses.asdict(sizes), sort_keys=True, default=str)
    path = Path(runs) / "offroad" / f"{name}_{hashlib.sha256(text.encode()).hexdigest()[:12]}.json"
    if path.exists():
        log(f"  {name} seed {sizes.demo.seed}: cached in {path}")
        return dict(json.loads(path.read_text())["rows"])
    start = time.perf_counter()
    values = compute()
    log(f"  {name} seed {sizes.demo.seed}: {time.perf_counter() - start:.0f} s")
    write_json_atomic(path, {"rows": list(values.items())})  # a list keeps the rows' order (the file sorts keys)
    return values


def better(values: dict, a: str, b: str, metric: str, lower: bool = False) -> bool:
    """Row ``a`` beats row ``b`` in ``metric`` by more than the larger std of the two."""
    x, y = values[a][metric], values[b][metric]
    spread = max(values[a].get(f"{metric}_std", 0.0), values[b].get(f"{metric}_std", 0.0))
    return (y - x if lower else x - y) > spread


def beats(values: dict, a: str, b: str, metrics: dict[str, str], claim: str, lower: Sequence[str] = ()) -> Finding:
    """``a`` beats ``b`` in every metric of ``metrics`` (metric -> its name); ``lower``: lower is better."""
    holds = all(better(values, a, b, m, m in lower) for m in metrics)
    evidence = ", ".join(f"{name} {_cell(values[a], m)} vs {_cell(values[b], m)}" for m, name in metrics.items())
    return Finding(claim, holds, evidence)


def not_beaten(values: dict, a: str, b: str, metrics: dict[str, str], claim: str, lower: Sequence[str] = ()) -> Finding:
    """``a`` is at ``b``'s level: ``b`` beats ``a`` (by more than the larger std) in none of ``metrics``."""
    holds = not any(better(values, b, a, m, m in lower) for m in metrics)
    evidence = ", ".join(f"{name} {_cell(values[a], m)} vs {_cell(values[b], m)}" for m, name in metrics.items())
    return Finding(claim, holds, evidence)


def chain(values: dict, rows: Sequence[str], metric: str, name: str, claim: str, lower: bool = False) -> Finding:
    """Each row of ``rows`` beats the one before it in ``metric``."""
    holds = all(better(values, b, a, metric, lower) for a, b in zip(rows, rows[1:]))
    return Finding(claim, holds, f"{name}: " + ", ".join(f"{r} {_cell(values[r], metric)}" for r in rows))


def markdown_table(values: dict, columns: dict[str, str]) -> str:
    """Rows of ``values`` (from ``aggregate``) with the ``columns`` (metric -> header), mean ± std."""
    lines = ["| row | " + " | ".join(columns.values()) + " |", "|---" * (len(columns) + 1) + "|"]
    lines += [f"| {label} | " + " | ".join(_cell(v, m) for m in columns) + " |" for label, v in values.items()]
    return "\n".join(lines)


def run_seeds(name: str, title: str, description: str, scale: Scale, seeds: int, out_dir: Path, runs: Path,
              seed_values: Callable[[OffroadSizes, Callable], dict], columns: dict[str, str],
              findings: Callable[[dict], list[Finding]], log: Callable = print,
              controls: Callable[[dict], list[Finding]] | None = None) -> dict:
    """Every seed's values (``seed_values(sizes, log)``, cached), aggregated; the findings and the positive
    ``controls`` checked on the means against the spread; ``<name>.json`` and ``<name>.md`` written to
    ``out_dir``. Returns the result."""
    log(f"{name}: {title}")
    scales = seed_scales(scale, seeds)
    sizes = [offroad_sizes(s) for s in scales]
    values = aggregate([per_seed(name, z, runs, lambda z=z: seed_values(z, log), log) for z in sizes], tuple(columns))
    checked = findings(values)
    seed_text = (f"{len(scales)} seed(s) ({', '.join(str(s.seed) for s in scales)}), each setting the synthetic worlds, "
                 "the simulated annotator and the encoder's initialisation and batches; values are mean ± sample std "
                 "(ddof 1) over seeds, and a finding holds only when the difference of means exceeds the larger std "
                 "of the rows it compares")
    lines = [f"## {title}", "", description, "", markdown_table(values, columns), "", f"`{name}`; {seed_text}.", "",
             "| paper's finding | holds here? | evidence |", "|---|---|---|"]
    lines += [f"| {f.claim} | {'yes' if f.holds else '**no**'} | {f.evidence} |" for f in checked]
    checked_controls = [dataclasses.asdict(f) for f in (controls(values) if controls else [])]
    report = "\n".join(lines + control_lines(checked_controls))
    result = {"name": name, "title": title, "description": description,
              "table": [{"label": k, **v} for k, v in values.items()], "scale": dataclasses.asdict(scales[0]),
              "sizes": json.loads(json.dumps(dataclasses.asdict(sizes[0]), default=str)),
              "findings": [dataclasses.asdict(f) for f in checked],
              "controls": checked_controls, "seeds": seed_text, "num_seeds": len(scales),
              "report": report}
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / f"{name}.json", result)
    write_bytes_atomic(out_dir / f"{name}.md", (report + "\n").encode())
    return result
