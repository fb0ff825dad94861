"""Sampled mutation testing: one AST mutation at a time, run against the module's own test files.

Usage (from the repository root, with the project's venv)::

    python tools/mutate.py jaxanom/offroad/risk.py jaxanom/mixture.py --per-module 12 --jobs 2 \\
        --out /tmp/mutants.jsonl
    python tools/mutate.py jaxanom/mixture.py --list          # the mutation sites, nothing run
    python tools/mutate.py jaxanom/mixture.py --sites 3 7 --diff   # what those mutants change
    python tools/mutate.py --summary /tmp/mutants.jsonl      # run / killed / survived per module

Each worker copies the working tree (without .git) to a temporary folder once; a mutant is the
module's source with one site changed (``ast.unparse`` of the whole module), written into that
copy and restored in ``finally`` - the checkout itself is never touched. The module's test files
(``TESTS`` below, or ``--tests``) then run in a fresh interpreter with ``-x -q -n 0`` under a
timeout: a failure or timeout kills the mutant, a pass means it survived. Before its mutants, each
module's unmutated ``ast.unparse`` must pass the same tests (a clean run), else it is skipped.

Mutations: comparison flips (``<``/``<=``, ``>``/``>=``, ``==``/``!=``, ``is``/``is not``,
``in``/``not in``), arithmetic swaps (``+``/``-``, ``*``/``/``, ``//``/``/``, ``**``/``*``),
numbers ``n -> n + 1`` (and ``1 -> 0``), ``True``/``False``, dropping a unary ``-`` or ``not``,
``and``/``or``, ``min``/``max`` (also ``minimum``/``maximum``, ``argmin``/``argmax``, ``any``/``all``,
``floor``/``ceil``) and dropping one keyword argument of a call. Error messages (``raise``),
f-strings, docstrings, annotations and decorators are not mutated. Sites are sampled per module with
a seeded generator, round-robin over the functions that hold them (stratified). Chosen because
mutmut 3 forks one process per mutant from a parent that has imported JAX, which deadlocks
(docs/decisions/mutation-testing.md). Not collected by pytest (it lives outside tests/).
"""
from __future__ import annotations

import argparse
import ast
import difflib
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = Path(tempfile.gettempdir()) / "jaxanom-mutants.jsonl"  # results stay out of the checkout

# Each module's test files: the ones that exercise it directly (a survivor here may still die
# elsewhere in the suite; the report says so).
TESTS = {
    "jaxanom/offroad/risk.py": ["tests/offroad/test_offroad_risk.py"],
    "jaxanom/offroad/active.py": ["tests/offroad/test_offroad_active.py"],
    "jaxanom/offroad/contrastive.py": ["tests/offroad/test_offroad_contrastive.py"],
    "jaxanom/offroad/crf.py": ["tests/offroad/test_offroad_crf.py"],
    "jaxanom/offroad/patches.py": ["tests/offroad/test_offroad_patches.py"],
    "jaxanom/offroad/pairs.py": ["tests/offroad/test_offroad_patches.py"],
    "jaxanom/offroad/encoder.py": ["tests/offroad/test_offroad_encoder.py"],
    "jaxanom/sml/boundaries.py": ["tests/sml/test_sml_boundaries.py"],
    "jaxanom/sml/policy.py": ["tests/sml/test_sml_policy.py"],
    "jaxanom/sml/postprocessing.py": ["tests/sml/test_sml_postprocess.py"],
    "jaxanom/sml/score.py": ["tests/sml/test_sml_score.py"],
    "jaxanom/sml/stats.py": ["tests/sml/test_sml_stats.py"],
    "jaxanom/metrics/accumulator.py": ["tests/metrics/test_metrics_accumulator.py"],
    "jaxanom/metrics/anomaly.py": ["tests/metrics/test_metrics_anomaly.py"],
    "jaxanom/metrics/components.py": ["tests/metrics/test_metrics_components.py"],
    "jaxanom/metrics/curve.py": ["tests/metrics/test_metrics_anomaly.py"],
    "jaxanom/metrics/ranking.py": ["tests/metrics/test_metrics_anomaly.py"],
    "jaxanom/metrics/roi.py": ["tests/metrics/test_metrics_roi.py"],
    "jaxanom/metrics/segmentation.py": ["tests/metrics/test_metrics_segmentation.py"],
    "jaxanom/mixture.py": ["tests/test_mixture.py"],
    "jaxanom/mmf/gan.py": ["tests/mmf/test_mmf_spade.py"],
    "jaxanom/mmf/gan_train.py": ["tests/mmf/test_mmf_spade.py"],
    "jaxanom/mmf/perceptual.py": ["tests/mmf/test_mmf_maps.py"],
    "jaxanom/mmf/synthesis.py": ["tests/mmf/test_mmf_maps.py", "tests/app/test_mmf_variants.py"],
    "jaxanom/mmf/training_free.py": ["tests/mmf/test_mmf_methods.py"],
    "jaxanom/mmf/uncertainty.py": ["tests/mmf/test_mmf_maps.py"],
}

COMPARE_SWAPS = {ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt, ast.Eq: ast.NotEq,
                 ast.NotEq: ast.Eq, ast.Is: ast.IsNot, ast.IsNot: ast.Is, ast.In: ast.NotIn, ast.NotIn: ast.In}
BINOP_SWAPS = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult,
               ast.FloorDiv: ast.Div, ast.Pow: ast.Mult, ast.Mod: ast.FloorDiv}
NAME_SWAPS = {"min": "max", "max": "min", "minimum": "maximum", "maximum": "minimum", "argmin": "argmax",
              "argmax": "argmin", "any": "all", "all": "any", "floor": "ceil", "ceil": "floor",
              "amin": "amax", "amax": "amin", "nanmin": "nanmax", "nanmax": "nanmin"}


def _call_name(call: ast.Call) -> str | None:
    func = call.func
    return func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else None


def _mutations(node: ast.AST) -> list[tuple[str, callable]]:
    """(description, edit) pairs for one node; ``edit`` changes the node in place."""
    out = []
    if isinstance(node, ast.Compare):
        for k, op in enumerate(node.ops):
            if type(op) in COMPARE_SWAPS:
                def edit(n, k=k, new=COMPARE_SWAPS[type(op)]):
                    n.ops[k] = new()
                out.append((f"{type(op).__name__} -> {COMPARE_SWAPS[type(op)].__name__}", edit))
    elif isinstance(node, (ast.BinOp, ast.AugAssign)) and type(node.op) in BINOP_SWAPS:
        new = BINOP_SWAPS[type(node.op)]
        out.append((f"{type(node.op).__name__} -> {new.__name__}", lambda n, new=new: setattr(n, "op", new())))
    elif isinstance(node, ast.Constant) and type(node.value) in (int, float):
        new = 0 if node.value == 1 else node.value + 1
        out.append((f"{node.value!r} -> {new!r}", lambda n, new=new: setattr(n, "value", new)))
    elif isinstance(node, ast.Constant) and isinstance(node.value, bool):
        out.append((f"{node.value} -> {not node.value}", lambda n: setattr(n, "value", not n.value)))
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.Not)):
        out.append((f"drop unary {type(node.op).__name__}", None))  # replaced by its operand
    elif isinstance(node, ast.BoolOp):
        new = ast.Or if isinstance(node.op, ast.And) else ast.And
        out.append((f"{type(node.op).__name__} -> {new.__name__}", lambda n, new=new: setattr(n, "op", new())))
    elif isinstance(node, ast.Call):
        name = _call_name(node)
        if name in NAME_SWAPS:
            def edit(n, new=NAME_SWAPS[name]):
                if isinstance(n.func, ast.Name):
                    n.func.id = new
                else:
                    n.func.attr = new
            out.append((f"{name} -> {NAME_SWAPS[name]}", edit))
        for k, kw in enumerate(node.keywords):
            if kw.arg is not None:
                out.append((f"drop keyword {kw.arg}=", lambda n, k=k: n.keywords.pop(k)))
    return out


class _Sites(ast.NodeTransformer):
    """Walks the module in a fixed order, numbering sites; applies site ``target`` if given."""

    def __init__(self, target: int | None = None):
        self.target, self.count, self.sites, self.scope = target, 0, [], ["<module>"]

    def _skip(self, node):
        return node  # not descended into: no mutation inside

    visit_Raise = visit_JoinedStr = _skip

    def visit_FunctionDef(self, node):
        """Defaults and body (after the docstring); not decorators or annotations."""
        self.scope.append(node.name)
        node.args.defaults = [self.visit(d) for d in node.args.defaults]
        node.args.kw_defaults = [d if d is None else self.visit(d) for d in node.args.kw_defaults]
        first = 1 if ast.get_docstring(node) is not None else 0
        node.body[first:] = [self.visit(s) for s in node.body[first:]]
        self.scope.pop()
        return node

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_ClassDef(self, node):
        self.scope.append(node.name)
        first = 1 if ast.get_docstring(node) is not None else 0
        node.body[first:] = [self.visit(s) for s in node.body[first:]]
        self.scope.pop()
        return node

    def visit_AnnAssign(self, node):
        if node.value is not None:
            node.value = self.visit(node.value)
        return node

    def visit_Expr(self, node):
        if isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            return node  # a bare string (docstring)
        return self.generic_visit(node)

    def generic_visit(self, node):
        node = super().generic_visit(node)
        for desc, edit in _mutations(node):
            here = self.count
            self.count += 1
            self.sites.append({"site": here, "line": getattr(node, "lineno", 0),
                               "scope": ".".join(self.scope[1:]) or "<module>", "mutation": desc})
            if here == self.target:
                if edit is None:
                    return node.operand
                edit(node)
        return node


def sites(source: str) -> list[dict]:
    walker = _Sites()
    walker.visit(ast.parse(source))
    return walker.sites


def mutant_source(source: str, site: int | None) -> str:
    """The module with site ``site`` mutated (``None``: unmutated, through the same unparse)."""
    tree = _Sites(site).visit(ast.parse(source))
    return ast.unparse(ast.fix_missing_locations(tree)) + "\n"


def sample(all_sites: list[dict], n: int, seed: int) -> list[dict]:
    """Up to ``n`` sites, round-robin over their functions in a seeded random order."""
    rng = random.Random(seed)
    by_scope = defaultdict(list)
    for s in all_sites:
        by_scope[s["scope"]].append(s)
    pools = [rng.sample(v, len(v)) for _, v in sorted(by_scope.items())]
    rng.shuffle(pools)
    picked = []
    while len(picked) < n and any(pools):
        for pool in pools:
            if pool and len(picked) < n:
                picked.append(pool.pop())
    return sorted(picked, key=lambda s: s["site"])


class Worker:
    """A private copy of the tree in which one module at a time is swapped and tested."""

    def __init__(self, cache_dir: str):
        self.root = Path(tempfile.mkdtemp(prefix="jaxanom-mutate-"))
        shutil.copytree(ROOT, self.root, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns(".git", "__pycache__", ".venv", "*.pyc"))
        # tests/conftest.py looks for the real data beside the tree: point it at the checkout's
        realdata = os.environ.get("JAXANOM_REALDATA", str(ROOT.parent / "shared" / "realdata"))
        self.env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "JAX_COMPILATION_CACHE_DIR": cache_dir,
                    "JAXANOM_REALDATA": realdata}

    def run(self, module: str, source: str, tests: list[str], timeout: float) -> tuple[str, float]:
        path = self.root / module
        original = path.read_text()
        start = time.monotonic()
        try:
            path.write_text(source)
            cmd = [sys.executable, "-m", "pytest", *tests, "-x", "-q", "-n", "0", "-p", "no:cacheprovider"]
            code = subprocess.run(cmd, cwd=self.root, env=self.env, timeout=timeout,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
            status = "survived" if code == 0 else "killed"
        except subprocess.TimeoutExpired:
            status = "timeout"
        finally:
            path.write_text(original)
        return status, time.monotonic() - start


def summary(path: str) -> None:
    """Markdown table: mutants run, killed (a failing test or a timeout) and survived per module."""
    rows = defaultdict(lambda: [0, 0, 0])
    for line in open(path):
        record = json.loads(line)
        row = rows[record["module"]]
        row[0] += 1
        row[1 if record["status"] in ("killed", "timeout") else 2] += 1
    print("| module | run | killed | survived |\n|---|---|---|---|")
    for module, (run, killed, survived) in rows.items():
        print(f"| {module} | {run} | {killed} | {survived} |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("modules", nargs="*")
    parser.add_argument("--tests", nargs="*", help="test files (default: TESTS[module])")
    parser.add_argument("--per-module", type=int, default=12)
    parser.add_argument("--sites", type=int, nargs="*", help="run exactly these site numbers")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--timeout-factor", type=float, default=3.0)
    parser.add_argument("--list", action="store_true", help="print the sites and stop")
    parser.add_argument("--diff", action="store_true", help="print the diffs of --sites and stop")
    parser.add_argument("--out", default=str(DEFAULT_OUT), help=f"results, appended (default: {DEFAULT_OUT})")
    parser.add_argument("--summary", metavar="JSONL", help="tabulate a results file and stop")
    args = parser.parse_args(argv)
    if args.summary:
        return summary(args.summary)

    chosen = {}
    for module in args.modules:
        all_sites = sites((ROOT / module).read_text())
        chosen[module] = ([s for s in all_sites if s["site"] in args.sites] if args.sites
                          else sample(all_sites, args.per_module, args.seed))
        if args.list:
            for s in (chosen[module] if args.sites else all_sites):
                print(module, json.dumps(s))
        if args.diff:
            source = (ROOT / module).read_text()
            for s in chosen[module]:
                before, after = mutant_source(source, None), mutant_source(source, s["site"])
                print("".join(difflib.unified_diff(before.splitlines(True), after.splitlines(True),
                                                   module, f"{module} site {s['site']}", n=0)))
    if args.list or args.diff:
        return

    cache_dir = tempfile.mkdtemp(prefix="jaxanom-mutate-xla-")
    workers = [Worker(cache_dir) for _ in range(args.jobs)]
    free = list(workers)
    lock = threading.Lock()

    def on_worker(fn, *a):
        with lock:
            worker = free.pop()
        try:
            return fn(worker, *a)
        finally:
            with lock:
                free.append(worker)

    with open(args.out, "a") as out, ThreadPoolExecutor(args.jobs) as pool:
        for module, picked in chosen.items():
            source = (ROOT / module).read_text()
            tests = args.tests or TESTS[module]
            status, clean = on_worker(lambda w: w.run(module, mutant_source(source, None), tests, 1800))
            print(f"{module}: clean run {status} in {clean:.0f} s", flush=True)
            if status != "survived":
                continue
            timeout = max(args.timeout_factor * clean, 60.0)

            def one(worker, site):
                result, seconds = worker.run(module, mutant_source(source, site["site"]), tests, timeout)
                return {"module": module, **site, "status": result, "seconds": round(seconds, 1)}

            for record in pool.map(lambda s: on_worker(one, s), picked):
                out.write(json.dumps(record) + "\n")
                out.flush()
                print(json.dumps(record), flush=True)
    for worker in workers:
        shutil.rmtree(worker.root, ignore_errors=True)
    shutil.rmtree(cache_dir, ignore_errors=True)


if __name__ == "__main__":
    main()
