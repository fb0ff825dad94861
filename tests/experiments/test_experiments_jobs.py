"""``python -m experiments --jobs``: the work done before the tables, in worker processes."""
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from experiments import cudam_table2, mmf_table2, msaam_table6
from experiments.__main__ import jobs_of, parse_args
from experiments.common import Scale, evaluation_cache, seed_scales
from experiments.jobs import Job, run_jobs
from experiments.offroad_common import cache_path, offroad_sizes

ROOT = Path(__file__).resolve().parents[2]


def test_jobs_run_in_worker_processes_and_a_failure_is_reported(tmp_path):
    written = [tmp_path / f"{i}.txt" for i in range(3)]
    jobs = [Job(f"write {i}", Path.write_text, (path, f"job {i}"), minutes=i) for i, path in enumerate(written)]
    jobs.append(Job("read a missing file", Path.read_text, (tmp_path / "missing",), minutes=5))
    share = tmp_path / "share.txt"  # each worker's share of an accelerator's memory
    jobs.append(Job("memory", subprocess.run, (["sh", "-c", f"echo $XLA_PYTHON_CLIENT_MEM_FRACTION > {share}"],), 1))
    failed = run_jobs(jobs, 2, tmp_path / "cache", log=lambda *_: None)
    assert [p.read_text() for p in written] == ["job 0", "job 1", "job 2"] and share.read_text() == "0.40\n"
    assert list(failed) == ["read a missing file"] and failed["read a missing file"].startswith("FileNotFoundError")
    other = tmp_path / "other.txt"
    assert run_jobs([Job("write", Path.write_text, (other, "x"), 1)], 1, tmp_path / "cache") == {}
    assert not other.exists()  # one process: the tables do the work themselves
    with pytest.raises(ValueError, match="processes: expected >= 1, got 0"):
        run_jobs(jobs, 0, tmp_path / "cache")


def test_table_jobs_train_each_network_folder_once_and_skip_cached_ones(tmp_path):
    scale, names = Scale.smoke(), ["cudam_table2", "msaam_table6"]
    per_seed = {s.seed: [row for m in (cudam_table2, msaam_table6) for row in m.rows(s)] for s in seed_scales(scale, 2)}
    rows = [row for seed_rows in per_seed.values() for row in seed_rows]
    folders = {row.network.run_key for row in rows}
    assert len(rows) > len(folders)  # the plain network (and its scaled-logit control) is shared
    jobs = jobs_of(names, scale, 2, tmp_path)
    assert sorted(job.label for job in jobs) == sorted(f"network {key}" for key in folders)
    for job in jobs:  # each job evaluates every network of its folder, with that folder's seed
        nets, job_scale, runs = job.args
        assert {n.run_key for n in nets} == {job.label.split()[-1]} and runs == tmp_path
        assert {n.key for n in nets} == {r.network.key for r in rows if r.network.run_key == nets[0].run_key}
        assert {n.key for n in nets} <= {r.network.key for r in per_seed[job_scale.seed]}
    first = next(job for job in jobs if len(job.args[0]) > 1)
    nets, job_scale, _ = first.args
    for net in nets[:-1]:  # all but one network of the folder evaluated: the folder's job remains
        evaluation_cache(net, job_scale, tmp_path).parent.mkdir(parents=True, exist_ok=True)
        evaluation_cache(net, job_scale, tmp_path).with_suffix(".npz").write_bytes(b"")
    assert first.label in {job.label for job in jobs_of(names, scale, 2, tmp_path)}
    evaluation_cache(nets[-1], job_scale, tmp_path).with_suffix(".npz").write_bytes(b"")
    assert first.label not in {job.label for job in jobs_of(names, scale, 2, tmp_path)}


def test_mmf_and_offroad_jobs_one_per_seed_until_cached(tmp_path):
    scale = Scale.smoke()
    jobs = jobs_of(["mmf_table2", "offroad_exp2", "offroad_table3"], scale, 3, tmp_path)
    assert sorted(job.label for job in jobs) == sorted([f"mmf_table2 seed {s}" for s in range(3)]
                                                       + [f"off-road seed {s}" for s in range(3)])
    offroad = [job for job in jobs if job.label.startswith("off-road")]
    assert all(job.args[0] == ("offroad_exp2", "offroad_table3") for job in offroad)  # one process per seed: M_A shared
    assert all(job.function is mmf_table2.build_parts for job in jobs if job.label.startswith("mmf"))
    sizes = offroad_sizes(seed_scales(scale, 3)[1])
    for name in ("offroad_exp2", "offroad_table3"):
        cache_path(name, sizes, tmp_path).parent.mkdir(parents=True, exist_ok=True)
        cache_path(name, sizes, tmp_path).write_text("{}")
    left = {job.label for job in jobs_of(["offroad_exp2", "offroad_table3"], scale, 3, tmp_path)}
    assert left == {"off-road seed 0", "off-road seed 2"}


@pytest.mark.parametrize("flag", ["--jobs", "--seeds"])
def test_command_line_rejects_a_non_positive_count(flag, capsys):
    with pytest.raises(SystemExit):
        parse_args([flag, "0"])
    assert f"{flag}: expected a positive integer, got 0" in capsys.readouterr().err
    assert parse_args([]).jobs == 2 and parse_args(["--jobs", "3"]).jobs == 3


def _alive(pid: int) -> bool:
    """A process that exists and is not a zombie (nobody may reap an orphan here)."""
    try:
        return Path(f"/proc/{pid}/status").read_text().split("State:")[1].split()[0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_killed_parent_takes_its_workers_with_it(tmp_path):
    script = textwrap.dedent("""
        import multiprocessing, os, time
        from concurrent.futures import ProcessPoolExecutor
        from experiments.jobs import end_with_parent
        if __name__ == "__main__":
            with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=end_with_parent) as pool:
                print(pool.submit(os.getpid).result(), flush=True)
                pool.submit(time.sleep, 120).result()
        """)
    errors = tmp_path / "stderr"  # the pool's resource tracker outlives the parent and writes here too
    with errors.open("w") as stderr, subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                                                      stderr=stderr, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}) as parent:
        line = parent.stdout.readline()
        assert line.strip().isdigit(), errors.read_text()
        worker = int(line)
        assert _alive(worker)
        parent.kill()
    deadline = time.monotonic() + 20
    while _alive(worker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(worker), f"worker {worker} outlived its killed parent"
