"""Run every benchmark in one go and (with ``--write``) rewrite ``benchmarks/RESULTS.md``.

    python -m benchmarks [--quick] [--only NAME ...] [--write]

Every ``benchmarks/bench_<name>.py`` module's ``run(quick)`` is called in turn; its rows are
printed as one markdown table per ``benchmark`` value, under the device and versions of
``timing.environment()``, each with a one-line reading of the times (jaxanom against every
peer measured in the same run). A module that fails is reported as failed, the others still run,
and the exit status is 1. Text below the ``NOTES`` marker line of an existing RESULTS.md (for
example measurements from another machine) is kept when the file is rewritten.
"""
from __future__ import annotations

import argparse
import datetime
import importlib
import importlib.util
import os
import platform
import sys
import time
import traceback
from pathlib import Path
from types import ModuleType

from benchmarks.timing import Unavailable

HERE = Path(__file__).parent
PACKAGE = __package__ or "benchmarks"
NOTES = "<!-- Hand-written notes: everything below this line is kept by `python -m benchmarks --write`. -->"


def discover(directory: Path = HERE) -> list[str]:
    """Names (``bench_<name>`` -> ``<name>``) of the benchmark modules in ``directory``."""
    return sorted(path.stem.removeprefix("bench_") for path in Path(directory).glob("bench_*.py"))


def load(name: str, directory: Path = HERE) -> ModuleType:
    """The module ``bench_<name>`` of ``directory`` (of this package when it is this folder)."""
    if Path(directory).resolve() == HERE.resolve():
        return importlib.import_module(f"{PACKAGE}.bench_{name}")
    spec = importlib.util.spec_from_file_location(f"bench_{name}", Path(directory) / f"bench_{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_all(names: list[str], quick: bool, directory: Path = HERE, log=print, after=None) -> dict[str, dict]:
    """``{name: {"rows", "reader", "seconds"}}`` or ``{name: {"error", "seconds"}}`` per module.

    ``reader(rows) -> str`` reads one table in a line: the module's own ``interpret`` if it has
    one, else ``interpret`` here. ``after(results)``, if given, is called after each module (so a
    run killed at a time limit keeps what it measured).
    """
    results = {}
    for name in names:
        log(f"running bench_{name}{' (quick)' if quick else ''} ...")
        start = time.perf_counter()
        try:
            module = load(name, directory)
            results[name] = {"rows": list(module.run(quick=quick)), "reader": getattr(module, "interpret", interpret)}
        except Unavailable as reason:
            results[name] = {"unavailable": str(reason)}
        except Exception:  # noqa: BLE001 -- one broken benchmark must not hide the others' results
            results[name] = {"error": traceback.format_exc(limit=3).strip()}
        results[name]["seconds"] = time.perf_counter() - start
        log(f"  {time.perf_counter() - start:.0f} s")
        if after is not None:
            after(results)
    return results


def interpret(rows: list[dict]) -> str:
    """One line reading a table: per peer, the range over cases of peer time / jaxanom time."""
    ours = {r["case"]: r["median_ms"] for r in rows if str(r["impl"]).startswith("jaxanom")}
    peers: dict[str, list[float]] = {}
    for r in rows:
        if not str(r["impl"]).startswith("jaxanom") and ours.get(r["case"], 0) > 0:
            peers.setdefault(str(r["impl"]), []).append(r["median_ms"] / ours[r["case"]])
    if not peers:
        times = [r["median_ms"] for r in rows]
        if len(times) == 1:
            return f"no peer in this run; {times[0]:.3g} ms."
        return f"no peer in this run; {min(times):.3g} to {max(times):.3g} ms over {len(rows)} cases."
    parts = []
    for peer, ratios in peers.items():
        low, high = min(ratios), max(ratios)
        span = f"{low:.2g}x" if f"{low:.2g}" == f"{high:.2g}" else f"{low:.2g}x to {high:.2g}x"
        verdict = ("about the same speed" if 0.95 <= low and high <= 1.05 else "jaxanom faster" if low > 1
                   else "jaxanom slower" if high < 1 else "jaxanom faster in some cases, slower in others")
        parts.append(f"{peer} takes {span} jaxanom's time ({verdict})")
    return "; ".join(parts) + "."


def columns(rows: list[dict]) -> list[str]:
    """Every key that occurs in ``rows``, in order of first appearance."""
    seen: dict[str, None] = {}
    for row in rows:
        seen.update(dict.fromkeys(row))
    return list(seen)


def tables(results: dict[str, dict]) -> str:
    """Markdown: per module, one table per ``benchmark`` value with its reading, or the failure."""
    from benchmarks.timing import markdown_table

    lines = []
    for name, result in results.items():
        lines += ["", f"## bench_{name} ({result['seconds']:.0f} s)", ""]
        if "error" in result:
            lines += ["**failed:**", "", "```", result["error"], "```"]
            continue
        if "unavailable" in result:
            lines += [result["unavailable"]]
            continue
        groups: dict[str, list[dict]] = {}
        for row in result["rows"]:
            groups.setdefault(str(row["benchmark"]), []).append(row)
        for benchmark, rows in groups.items():
            lines += [f"### {benchmark}", "", markdown_table(rows, columns(rows)), "",
                      f"Reading: {result['reader'](rows)}", ""]
    return "\n".join(lines).strip("\n")


def header(environment: dict[str, str], quick: bool) -> str:
    """Date, machine and versions."""
    versions = ", ".join(f"{k} {v}" for k, v in environment.items() if k not in ("device", "cpu"))
    return "\n".join([
        f"Run on {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')} with `python -m benchmarks"
        f"{' --quick' if quick else ''}`.",
        "",
        f"- device: {environment.get('device', '?')}",
        f"- machine: {platform.platform()}, {environment.get('cpu', '?')}, {os.cpu_count()} CPU cores",
        f"- versions: {versions}",
        "",
        "Times are medians in ms; a peer's ratio is its time over jaxanom's in the same run (above 1: jaxanom "
        "is faster). Peers are measured in the same process on the same inputs, and the scripts check "
        "that they compute the same values before timing.",
    ])


def results_markdown(results: dict[str, dict], environment: dict[str, str], quick: bool, notes: str = "") -> str:
    """The RESULTS.md text: header, tables, then the kept ``notes`` under the ``NOTES`` marker."""
    return f"# Benchmark results\n\n{header(environment, quick)}\n\n{tables(results)}\n\n{NOTES}\n{notes}"


def kept_notes(path: Path) -> str:
    """The text below the ``NOTES`` marker of an existing results file ("" if none)."""
    text = path.read_text() if path.exists() else ""
    return text.partition(NOTES + "\n")[2] if NOTES in text else ""


def main(argv=None, directory: Path = HERE) -> int:
    available = discover(directory)
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="each module's quick (small) variant")
    parser.add_argument("--only", nargs="+", choices=available, metavar="NAME",
                        help=f"modules to run (default: all of {', '.join(available)})")
    parser.add_argument("--write", action="store_true", help="rewrite the results file (see --results)")
    parser.add_argument("--results", type=Path, default=Path(directory) / "RESULTS.md",
                        help="the results file that --write rewrites (default: RESULTS.md beside the modules)")
    args = parser.parse_args(argv)

    from benchmarks.timing import environment

    env = environment()
    print(", ".join(f"{k}: {v}" for k, v in env.items()))
    path = args.results
    notes = kept_notes(path)

    def write(results):
        from jaxanom.io import write_bytes_atomic

        write_bytes_atomic(path, results_markdown(results, env, args.quick, notes).encode())

    results = run_all(args.only or available, args.quick, directory, after=write if args.write else None)
    print(results_markdown(results, env, args.quick, notes))
    if args.write:
        print(f"wrote {path}")
    return 1 if any("error" in r for r in results.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
