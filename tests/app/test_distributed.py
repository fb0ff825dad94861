"""Multi-host training for real: two processes joined by ``jax.distributed`` (``train --distributed``).

The cluster is a fake one-node SLURM job (the environment variables SLURM sets), so
``jax.distributed.initialize()`` detects it as it would on a real cluster; the CPU processes
talk over gloo. (Two processes read different shards of the data, so their global batches are
not those of one process with two devices: the runs agree in kind, not bit for bit.)
"""
import json
import os
import random
import subprocess
import sys

import jax
import numpy as np

from jaxanom.app.experiment import load_variables

from conftest import OPT_FLAG

CONFIG = """
from jaxanom.app.experiment import Experiment
from jaxanom.train.segmenter import TrainConfig
experiment = Experiment(train_frames=8, height=32, width=64, crop=(32, 64), batch_size=4,
                        train=TrainConfig(run_dir="", steps=3, save_every=2, eval_every=100))
"""
TRAIN = "import sys; from jaxanom.cli import main; sys.exit(main(sys.argv[1:]))"


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SLURM_", "OMPI_", "XLA_FLAGS"))}
    env.update(extra, JAX_PLATFORMS="cpu", XLA_FLAGS=OPT_FLAG)  # the suite's compile setting only
    return env


def test_two_processes_join_one_mesh_and_train(tmp_path):
    config = tmp_path / "config.py"
    config.write_text(CONFIG)
    command = [sys.executable, "-c", TRAIN, "train", "--config", str(config), "--no-progress", "--distributed",
               "--out", str(tmp_path / "run")]
    job = str(random.randrange(10**5, 10**6))  # the coordinator's port follows from the job id
    workers = [subprocess.Popen(command, env=_env(SLURM_JOB_ID=job, SLURM_NTASKS="2", SLURM_PROCID=str(i),
                                                  SLURM_LOCALID=str(i), SLURM_STEP_NODELIST="localhost",
                                                  SLURM_NODELIST="localhost"),
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for i in range(2)]
    outputs = [worker.communicate(timeout=600)[0] for worker in workers]
    assert [worker.returncode for worker in workers] == [0, 0], outputs
    assert all("trained 3 steps on 2 devices (2 processes)" in output for output in outputs), outputs
    assert json.loads((tmp_path / "run" / "experiment.json").read_text())["train"]["distributed"] is True
    steps = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert [s["step"] for s in steps if "train/loss" in s] == [1, 2, 3]
    assert all(np.isfinite(s["train/loss"]) for s in steps if "train/loss" in s)
    _, variables = load_variables(tmp_path / "run")
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree.leaves(variables))


JOIN = ("import jax; from jaxanom.train.sharding import initialize_distributed; initialize_distributed(); "
        "print('joined', jax.process_index(), 'of', jax.process_count(), flush=True)")


def _free_port() -> int:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _jax_env(port: int, index: int, processes: int = 2, timeout: int = 60) -> dict:
    """The environment variables the README and the error messages name (no cluster manager)."""
    return _env(JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}", JAX_NUM_PROCESSES=str(processes),
                JAX_PROCESS_ID=str(index), JAXANOM_DISTRIBUTED_TIMEOUT=str(timeout))


def test_the_documented_environment_variables_join_two_processes():
    port = _free_port()
    workers = [subprocess.Popen([sys.executable, "-c", JOIN], env=_jax_env(port, i), stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True) for i in range(2)]
    outputs = [worker.communicate(timeout=300)[0] for worker in workers]
    assert [worker.returncode for worker in workers] == [0, 0], outputs
    assert [output.strip().splitlines()[-1] for output in outputs] == ["joined 0 of 2", "joined 1 of 2"], outputs


def test_process_zero_whose_peers_never_join_ends_with_one_line(tmp_path):
    """JAX would abort process 0 from C++ with a stack trace; the command ends in one line, exit 2."""
    port = _free_port()
    command = [sys.executable, "-c", TRAIN, "train", "--distributed", "--no-progress", "--out", str(tmp_path / "run")]
    done = subprocess.run(command, env=_jax_env(port, 0, timeout=2), capture_output=True, text=True, timeout=300)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert f"not every process joined the run at 127.0.0.1:{port} within 2 s" in lines[0]
    assert "JAX_NUM_PROCESSES" in lines[0] and not (tmp_path / "run").exists()
