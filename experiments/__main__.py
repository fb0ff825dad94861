"""Run the paper-table experiments and write ``experiments/RESULTS.md``.

    python -m experiments                         # every table on synthetic scenes, 3 seeds (~2.5 h on 2 cores)
    python -m experiments --only cudam_table2     # one table
    python -m experiments --size 64 128 --train-frames 128 --steps 300   # smaller networks (RESULTS.md)
    python -m experiments --cityscapes /data/cityscapes --anomaly road_anomaly:/data/RoadAnomaly --out results/
    python -m experiments --smoke                 # the same code on tiny networks, into experiments/smoke/

Networks are cached in ``--runs`` by configuration, so tables that share a network train it once
and a rerun only evaluates. Before the tables, ``--jobs`` processes (default 2) train every network
and compute every seed they need (``experiments.jobs``); the tables then restore them. RESULTS.md
is rewritten after every table from the ``<name>.json`` files present in ``--out``.

``--out`` records how its results were made (``made_by.json``), and every table in it was made
so: a smoke run writes into ``experiments/smoke/`` by default and refuses a folder holding results
of a full run (a folder with results and no record counts as one), so it never replaces them, and
a full run refuses a folder holding a smoke run's results, so that no smoke table ever stands
under a full run's label (RESULTS.md's smoke banner is the folder's).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib
import json
import sys
import time
import traceback
from pathlib import Path

from experiments.common import (ANOMALY_READERS, COMPETENT_MIOU, HERE, RUNS, Scale, matched_sigma, matched_tau,
                                report, run_table, table_jobs, warmup_steps)
from experiments.jobs import Job, run_jobs
from experiments.offroad_common import seed_jobs
from experiments.stats import REPLICATES
from jaxanom.io import write_bytes_atomic, write_json_atomic

# Ordered so that the shared networks (plain, CuDAM) are trained by the first tables.
EXPERIMENTS = ("sml_table3_table7", "cudam_table2", "msaam_table6", "cudam_table3", "cudam_table5",
               "cudam_fig5", "cudam_fig6", "sml_scarce_stats", "offroad_exp2", "offroad_table2", "offroad_table3",
               "mmf_table2")
SMOKE_OUT = HERE / "smoke"
MADE_BY = "made_by.json"  # how the results in an --out folder were made: {"smoke": bool, "command": str}


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m experiments", description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=EXPERIMENTS, default=list(EXPERIMENTS), metavar="NAME",
                        help=f"experiments to run (default: all of {', '.join(EXPERIMENTS)})")
    parser.add_argument("--steps", type=int, help="training steps per network (default: Scale's)")
    parser.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), help="frame height and width (default: Scale's)")
    parser.add_argument("--train-frames", type=int, help="synthetic training scenes (default: Scale's)")
    parser.add_argument("--seeds", type=int, default=3,
                        help="train every network once per seed (seed, seed + 1, ...); tables give mean ± std "
                        "(default: %(default)s)")
    parser.add_argument("--jobs", type=int, default=2,
                        help="processes that train the networks and compute the seeds before the tables run "
                        "(default: %(default)s, about 1.4x the throughput of one on 2 CPU cores; 1: the tables do it)")
    parser.add_argument("--smoke", action="store_true",
                        help="the same code on tiny networks trained for a few steps, into experiments/smoke/ unless "
                        "--out says otherwise; minutes, not seconds: 31 CPU-minutes measured with 3 seeds (about 20 "
                        "minutes on 2 idle cores, mostly compiling); --seeds 1 and --only shorten it")
    parser.add_argument("--cityscapes", metavar="ROOT", help="train on Cityscapes instead of synthetic scenes")
    parser.add_argument("--anomaly", metavar="READER:ROOT",
                        help="score a real anomaly dataset: road_anomaly:<root> or smiyc:<track root>")
    parser.add_argument("--out", type=Path,
                        help="where tables and RESULTS.md go (default: experiments/, with --smoke experiments/smoke/)")
    parser.add_argument("--runs", type=Path, default=RUNS, help="trained networks (default: experiments/runs/)")
    args = parser.parse_args(argv)
    for name in ("jobs", "seeds", "steps", "train_frames"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')}: expected a positive integer, got {value}")
    if args.steps is not None and args.steps <= warmup_steps(args.steps):
        parser.error(f"--steps: expected at least 2 (the networks warm up for {warmup_steps(args.steps)} step(s) and "
                     f"need one more to train), got {args.steps}")
    if args.size is not None and not all(n >= 16 and n % 16 == 0 for n in args.size):
        parser.error(f"--size: expected H and W as positive multiples of 16 (the networks' output stride), "
                     f"got {' '.join(map(str, args.size))}")
    if args.anomaly is not None:
        reader, _, root = args.anomaly.partition(":")
        if reader not in ANOMALY_READERS or not root:
            parser.error(f"--anomaly: expected READER:ROOT with READER in {', '.join(ANOMALY_READERS)}, "
                         f"got {args.anomaly!r}")
        if not Path(root).is_dir():
            parser.error(f"--anomaly: the folder {root} does not exist")
    if args.cityscapes is not None and not Path(args.cityscapes).is_dir():
        parser.error(f"--cityscapes: the folder {args.cityscapes} does not exist")
    args.out = args.out or (SMOKE_OUT if args.smoke else HERE)
    if args.smoke and holds_results(args.out) and not made_by_smoke(args.out):
        parser.error(f"--out {args.out}: holds the results of a full run, which a smoke run would overwrite; "
                     f"choose another folder (the default for --smoke is {SMOKE_OUT})")
    if not args.smoke and holds_results(args.out) and made_by_smoke(args.out):
        parser.error(f"--out {args.out}: holds the results of a smoke run, which a full run's tables would join "
                     "under one label; choose another folder, or delete that one first")
    return args


def holds_results(out: Path) -> bool:
    """Whether ``out`` holds results: RESULTS.md, a table's JSON or a real-data table."""
    results = [out / "RESULTS.md", *(out / f"{name}.json" for name in EXPERIMENTS), *out.glob("real_*.md")]
    return any(path.exists() for path in results)


def made_by_smoke(out: Path) -> bool:
    """Whether ``out``'s ``MADE_BY`` record says a smoke run wrote it."""
    made_by = out / MADE_BY
    return made_by.is_file() and json.loads(made_by.read_text()).get("smoke") is True


def scale_from(args: argparse.Namespace) -> Scale:
    scale = Scale.smoke() if args.smoke else Scale()
    height, width = args.size or (None, None)
    changes = {"steps": args.steps, "height": height, "width": width, "train_frames": args.train_frames,
               "cityscapes_root": args.cityscapes, "anomaly": args.anomaly}
    return dataclasses.replace(scale, **{k: v for k, v in changes.items() if v is not None})


def main(argv=None) -> None:
    args = parse_args(argv)
    scale = scale_from(args)
    write_json_atomic(args.out / MADE_BY, {"smoke": args.smoke, "command": " ".join(["python -m experiments",
                                                                                     *(argv or sys.argv[1:])])})
    import jax

    jax.config.update("jax_compilation_cache_dir", str(args.runs / "jax_cache"))
    run_jobs(jobs_of(args.only, scale, args.seeds, args.runs), args.jobs, args.runs / "jax_cache")
    failures = {}
    for name in args.only:
        start = time.perf_counter()
        module = importlib.import_module(f"experiments.{name}")
        try:
            run = getattr(module, "run", None)
            if run is not None:  # an experiment that is not a table of (network, score) rows
                run(scale, args.seeds, args.out, args.runs, description=describe(module))
            else:
                run_table(module.NAME, module.TITLE, module.rows, module.findings, scale, args.out, args.runs,
                          description=describe(module), seeds=args.seeds, controls=getattr(module, "controls", None))
        except Exception:  # noqa: BLE001 -- e.g. a diverged network: report it, run the other tables
            failures[name] = traceback.format_exc(limit=4).strip()
            print(failures[name])
        print(f"{name}: {'failed' if name in failures else 'done'} in {time.perf_counter() - start:.0f} s")
        write_results(args.out, failures)
    print(f"results in {args.out / 'RESULTS.md'}")
    return 1 if failures else 0


def jobs_of(names, scale: Scale, seeds: int, runs: Path) -> list[Job]:
    """The work of the experiments ``names`` that ``run_jobs`` can do before them: one job per network
    folder of the (network, score) tables (shared folders once), per MMF seed and per off-road seed."""
    modules = [importlib.import_module(f"experiments.{name}") for name in names]
    tables = [m for m in modules if not hasattr(m, "run")]
    work = table_jobs(lambda s: [row for m in tables for row in m.rows(s)], scale, seeds, runs) if tables else []
    work += [job for m in modules if hasattr(m, "jobs") for job in m.jobs(scale, seeds, runs)]
    return work + seed_jobs([n for n in names if n.startswith("offroad_")], scale, seeds, runs)


def describe(module) -> str:
    """The experiment file's docstring without its command line, as one paragraph."""
    text = " ".join(line.strip() for line in module.__doc__.split("\n\n    python -m")[0].splitlines())
    return " ".join(text.split())


def write_results(out_dir: Path, failures: dict[str, str] | None = None) -> Path:
    """Rewrite ``RESULTS.md`` in ``out_dir`` from the experiment JSON files there (and this run's failures),
    followed by the real-data tables (``real_*.md``, written by ``python -m experiments.real_<name>``)."""
    failures = failures or {}
    results = [json.loads((out_dir / f"{name}.json").read_text()) for name in EXPERIMENTS
               if name not in failures and (out_dir / f"{name}.json").exists()]
    real = [path.read_text() for path in sorted(out_dir.glob("real_*.md"))]
    smoke = ("> **A smoke run** (`python -m experiments --smoke`): tiny networks trained for a few steps show that "
             "the code runs; their findings say nothing about the papers.\n\n" if made_by_smoke(out_dir) else "")
    text = smoke + summary(results, failures) + real_section(real) + "\n"
    return write_bytes_atomic(out_dir / "RESULTS.md", text.encode())


def real_section(tables: list[str]) -> str:
    """The real-data tables under one heading, each table's headings one level down ("" without any)."""
    if not tables:
        return ""
    demoted = ["\n".join("#" + line if line.startswith("#") else line for line in text.strip().splitlines())
               for text in tables]
    return "\n\n# Real data: the networks and claims on real frames (experiments/real_*.py)\n\n" + "\n\n".join(demoted)


PAPERS = (("SML", "sml_"), ("CuDAM", "cudam_"), ("MSAAM", "msaam_"), ("MMF", "mmf_"), ("off-road", "offroad_"))


def verdict(result: dict, finding: dict) -> tuple[str, str]:
    """``(kind, note)`` of one finding: kind ``"holds"``, ``"fails"`` or ``"untested"``; the note says why it
    could not be tested, or how it was decided where it has no paired interval or no mIoU check."""
    failed = [c["claim"] for c in result.get("controls", []) if not c["holds"]]
    reasons = [finding["untested_because"]] if finding.get("tested") is False else []
    lowest = min((row["miou"] for row in result.get("table", []) if "miou" in row), default=None)
    if "tested" not in finding and lowest is not None and lowest < COMPETENT_MIOU:  # a table from before the bar
        reasons.append(f"its networks reach {lowest:.1f}% mIoU at the lowest (< {COMPETENT_MIOU:.0f}%): a table of "
                       "the earlier tiny-network regime, not rerun on the competent one")
    reasons += [f"the table's positive control failed (points at a bug): {'; '.join(failed)}"] if failed else []
    if reasons:
        return "untested", "; ".join(reasons)
    notes = []
    if not any(c.get("low") is not None for c in finding.get("intervals", [])):
        notes.append("no paired interval: decided by the difference of means against the larger std over seeds")
    if finding.get("tested") is None:
        notes.append(f"not checked against the {COMPETENT_MIOU:.0f}% mIoU bar (no segmenter mIoU for its rows)")
    return ("holds" if finding["holds"] else "fails"), "; ".join(notes)


def paper_lines(results: list[dict]) -> list[str]:
    """Per paper: the findings that hold, those that fail in a competent regime, those not testable here."""
    heads = {"holds": f"Holds (every network compared at >= {COMPETENT_MIOU:.0f}% mIoU and the paired interval "
                      "excludes 0, unless a note says otherwise):",
             "fails": f"Fails in a competent regime (every network compared at >= {COMPETENT_MIOU:.0f}% mIoU, unless "
                      "a note says no mIoU bar applies):",
             "untested": "Could not be tested here (the evidence is in the table's section):"}
    lines = []
    for paper, prefix in PAPERS:
        found = [(r, f, *verdict(r, f)) for r in results if r["name"].startswith(prefix) for f in r["findings"]]
        if not found:
            continue
        lines += ["", f"### {paper}"]
        for kind, head in heads.items():
            items = [f"- `{r['name']}`: {f['claim']}" + ("" if kind == "untested" else f" ({f['evidence']})")
                     + (f" — {note}" if note else "") for r, f, k, note in found if k == kind]
            lines += ["", head, "", *(items or ["- none"])]
    return lines


def summary(results: list[dict], failures: dict[str, str] | None = None) -> str:
    """The RESULTS.md text: set-up, per paper the findings that hold / fail in a competent regime / could not
    be tested, every table, then failed experiments."""
    failed = [f"\n## {name}: failed\n\n```\n{text}\n```" for name, text in (failures or {}).items()]
    if not results:
        return "\n".join(["# Experiments\n\nNo experiment has completed yet: `python -m experiments`.", *failed])
    scale = Scale(**{"model": "deeplabv3plus_tiny", **results[0]["scale"]})  # results before the model field: tiny
    kinds = [verdict(r, f)[0] for r in results for f in r["findings"]]
    data = f"Cityscapes at `{scale.cityscapes_root}`" if scale.cityscapes_root else (
        f"{scale.train_frames} synthetic training scenes of {scale.height} x {scale.width}")
    anomaly = scale.anomaly or f"{scale.anomaly_frames} synthetic `{scale.anomaly_split}` frames"
    lines = [
        "# Experiments: the papers' tables on a small budget",
        "",
        f"Written by `python -m experiments` on {datetime.date.today().isoformat()}. Defaults of the SML, CuDAM "
        "and MSAAM tables (the MMF and off-road tables state their own networks, frames, region and AP "
        "convention in their descriptions, e.g. MMF: four networks, frames scored inside the road ROI, "
        f"envelope AP): every network is `{scale.model}` (a DeepLabV3+, output stride 16; "
        "`docs/decisions/baselines.md`) trained for the steps its table states, batch "
        f"{scale.batch_size}, on {data}, with AdamW (lr 2e-3) instead of the papers' SGD schedule. SML "
        f"statistics come from {scale.stats_frames} training frames; anomaly metrics pool all non-void pixels "
        f"of {anomaly}; mIoU is on {scale.val_frames} validation frames. Numbers are percent: AP is the step sum "
        "(scikit-learn's average precision), FPR95 the FPR at the first ROC point with TPR >= 95% (Fishyscapes' "
        "convention), AUROC the trapezoid. Rows with the same network hash share one trained network.",
        "",
        *seed_lines(results),
        *other_sizes(results),
        "",
        f"CuDAM's tau and sigma are rescaled to this run's attention-map size so that `tau * M_att` keeps the "
        f"paper's magnitude: tau = {matched_tau(scale):.4g} (paper: 5e4 on 180 x 180 maps), sigma = "
        f"{matched_sigma(scale.height, scale.width):.4g} (paper: 2e4 on 256 x 512 maps). The paper's literal "
        "values are rows of their own (Table II `cudam` score, Fig. 6). At the \"output\" position (the paper's "
        "surface, Table V) the map covers the whole frame, and tau and sigma are rescaled to its H x W positions.",
        "",
        f"**Of {len(kinds)} qualitative findings of the papers, {kinds.count('holds')} hold here, "
        f"{kinds.count('fails')} fail, and {kinds.count('untested')} could not be tested** (a network compared is "
        f"below {COMPETENT_MIOU:.0f}% mIoU, the rows compared cannot differ here (identical outputs, or a metric "
        "saturated in every replicate), or the table's positive control failed). The synthetic data was not "
        "changed to make any of them hold.",
        "",
        "## Findings per paper",
        *paper_lines(results),
        "",
        "## Tables",
        "",
        "| experiment | hold | fail | not testable | positive controls passing |",
        "|---|---|---|---|---|",
        *(f"| [{r['title']}](#{_anchor(r['title'])}) | {counts.count('holds')} | {counts.count('fails')} | "
          f"{counts.count('untested')} | {control_count(r)} |"
          for r in results for counts in [[verdict(r, f)[0] for f in r["findings"]]]),
    ]
    for result in results:
        if "report" in result:  # an experiment that renders its own table (the off-road ones)
            lines += ["", result["report"]]
            continue
        lines += ["", report(result), "",
                  f"Curves: [{result['name']}_roc.png]({result['name']}_roc.png), "
                  f"[{result['name']}_pr.png]({result['name']}_pr.png)."]
    return "\n".join(lines + failed)


def control_count(result: dict) -> str:
    controls = result.get("controls", [])
    return f"{sum(c['holds'] for c in controls)} / {len(controls)}" if controls else "none yet"


def seed_lines(results: list[dict]) -> list[str]:
    """What RESULTS.md says about seeds and about how a finding is decided."""
    counts = {r["name"]: r.get("num_seeds", 1) for r in results}
    single = [name for name, n in counts.items() if n == 1]
    unpaired = [r["name"] for r in results if not r.get("paired")]
    lines = [f"**How a finding is decided.** Each table states its seeds. With several seeds a value is the mean ± "
             "sample std (ddof 1) over seeds (each seed sets the network's initialisation, the shuffling and the "
             "synthetic scenes). Rows are compared **paired**: a hierarchical bootstrap "
             f"({REPLICATES} replicates, fixed seed) resamples the seeds with replacement and, inside each drawn seed, its "
             "anomaly frames (and validation frames, for mIoU) with replacement; a row's replicate is the mean over the "
             "drawn seeds of its metric on the drawn frames, and every row of a table uses the same draws (same seeds, "
             "frames and networks). **A finding holds when the 95% percentile interval of the paired difference "
             "lies entirely on the paper's side of 0**; evidence reads e.g. \"AP 20.60 vs 13.30, Δ +7.30 [+2.10, "
             "+12.00]\" (Δ: the difference of the means; [ ]: its interval). A finding is **tested** only where every "
             f"network of the rows it compares reaches {COMPETENT_MIOU:.0f}% mIoU on the validation frames (a finding "
             "that fails below that says little about the paper), and only where its rows can differ: a comparison "
             "whose rows have the same value in every bootstrap replicate (e.g. scene coverage at 100% in every frame) "
             "is untested. Positive controls are rows built so that the "
             "mechanism must help; a failing control points at a bug here, and its table's findings count as not "
             "testable."]
    if single:
        lines[0] += f" Tables with a single seed ({', '.join(single)}): the interval covers frames only, not seeds."
    if unpaired:
        lines[0] += (f" Tables without paired intervals ({', '.join(unpaired)}): a finding holds when the difference of "
                     "means exceeds the larger std over seeds; their findings say so.")
    return lines


def other_sizes(results: list[dict]) -> list[str]:
    """A line naming the tables whose frames or training scenes differ from the first table's (the
    off-road experiments, with ``"sizes"`` of their own, describe them in their tables)."""
    def size(r):
        s = r["scale"]
        return s["height"], s["width"], s["train_frames"], s["steps"], s.get("model", "deeplabv3plus_tiny")

    others = [f"`{r['name']}` ({h} x {w}, {n} scenes, {steps} steps, `{model}`)"
              for r in results if "sizes" not in r for h, w, n, steps, model in [size(r)] if size(r) != size(results[0])]
    return (["", "**Other sizes.** Trained at another size, length or network than stated above: " + ", ".join(others)
             + "."] if others else [])


def _anchor(title: str) -> str:
    """GitHub's anchor of a markdown heading."""
    kept = "".join(c for c in title.lower() if c.isalnum() or c in " -_")
    return kept.replace(" ", "-")


if __name__ == "__main__":
    sys.exit(main())
