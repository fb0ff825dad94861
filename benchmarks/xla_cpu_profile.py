"""XLA:CPU per-op time of a jitted function, summed by pass (forward, backward, update) and kind.

``profile_table(run, hlo_text)`` traces ``calls`` calls of ``run`` with ``jax.profiler`` (the CPU
runtime records one event per executed HLO instruction, named after it), and sorts each event
by the instruction in ``hlo_text`` (``compiled.as_text()``): its pass from the ``op_name``
metadata (``transpose(jvp(...))``: backward; ``jvp(...)``: forward; else update), its kind from
the opcode and, for a fusion, the operations fused in it (dot, reduce, transpose or copy, else
element-wise). Times are wall ms per call: read them as shares, not as CPU time.
"""
from __future__ import annotations

import collections
import glob
import gzip
import json
import re
import tempfile

import jax

_INSTRUCTION = re.compile(r"^\s+(?:ROOT )?%?([\w.\-]+) = .*? ([a-z][\w\-]*)\(")


def _computations(hlo_text: str) -> dict[str, list[str]]:
    comps, current = {}, None
    for line in hlo_text.splitlines():
        if line and not line.startswith(" ") and line.rstrip().endswith("{"):
            current = line.split()[1 if line.startswith("ENTRY") else 0].lstrip("%")
            comps[current] = []
        elif current and line.startswith("  "):
            comps[current].append(line)
    return comps


def _opcodes(comps: dict, name: str) -> collections.Counter:
    ops = collections.Counter()
    for line in comps.get(name, []):
        if m := _INSTRUCTION.match(line):
            ops[m.group(2)] += 1
        for called in re.findall(r"calls=%?([\w.\-]+)", line):
            ops += _opcodes(comps, called)
    return ops


def classify(hlo_text: str) -> dict[str, tuple[str, str]]:
    """Instruction name -> (pass, kind) for every instruction of ``hlo_text``."""
    comps = _computations(hlo_text)
    kinds = {}
    for lines in comps.values():
        for line in lines:
            m = _INSTRUCTION.match(line)
            if not m:
                continue
            name, opcode = m.groups()
            called = re.findall(r"calls=%?([\w.\-]+)", line)
            op_names = (re.findall(r'op_name="([^"]*)"', line)
                        or re.findall(r'op_name="([^"]*)"', "".join(comps.get(called[0], []) if called else [])))
            where = op_names[-1] if op_names else ""
            phase = "backward" if "transpose(jvp(" in where else "forward" if "jvp(" in where else "update"
            kind = opcode
            if opcode == "fusion":
                ops = _opcodes(comps, called[0])
                kind = ("dot" if ops["dot"] or ops["convolution"] else "reduce" if ops["reduce"]
                        else "transpose/copy" if ops["transpose"] or ops["copy"] else "element-wise")
            kinds[name] = (phase, kind)
    return kinds


def profile_table(run, hlo_text: str, calls: int = 3) -> str:
    """Markdown table: ms per call and share of the traced time by (pass, kind), largest first."""
    run()
    with tempfile.TemporaryDirectory() as log_dir:
        jax.profiler.start_trace(log_dir, create_perfetto_trace=True)
        for _ in range(calls):
            run()
        jax.profiler.stop_trace()
        with gzip.open(glob.glob(f"{log_dir}/**/perfetto_trace.json.gz", recursive=True)[0]) as f:
            trace = json.load(f)
    kinds = classify(hlo_text)
    ms, count = collections.Counter(), collections.Counter()
    for event in trace["traceEvents"] if isinstance(trace, dict) else trace:
        if event.get("ph") == "X" and event.get("name") in kinds:
            ms[kinds[event["name"]]] += event.get("dur", 0) / 1e3 / calls
            count[kinds[event["name"]]] += 1
    total = sum(ms.values())
    lines = ["| pass | kind | ms per call | share | ops |", "|---|---|---|---|---|"]
    lines += [f"| {p} | {k} | {v:.3g} | {100 * v / total:.1f}% | {count[(p, k)] // calls} |"
              for (p, k), v in ms.most_common()]
    return "\n".join(lines + [f"| all | | {total:.3g} | 100% | {sum(count.values()) // calls} |"])
