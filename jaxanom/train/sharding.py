"""Data parallelism: one mesh axis "data" over every device of every host.

Parameters and optimizer state are replicated (``P()``), batches are split along their first
axis (``P("data")``); XLA inserts the gradient all-reduce, and BatchNorm statistics are those of
the global batch. The same code runs on one CPU, eight GPUs or a multi-host pod. The mesh axis
is ``AxisType.Auto`` (sharding propagated by the compiler), so model code needs no sharding
annotations.
"""
from __future__ import annotations

import os
import socket
import sys
import threading
import time
from typing import Sequence

import jax
import numpy as np
from jax.sharding import AxisType, Mesh, NamedSharding, PartitionSpec as P

DATA = "data"


def initialize_distributed(timeout: int | None = None) -> None:
    """Join a multi-host run (``jax.distributed.initialize``); call before any other JAX work.

    The coordinator, process count and id are detected from the cluster environment
    (TPU pods, SLURM, Open MPI, ...), as ``jax.distributed.initialize`` documents, or read from
    ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID``. A second call is a
    no-op, so a command may join early and the train loop still asks. ``timeout`` (default
    ``$JAXANOM_DISTRIBUTED_TIMEOUT`` or 300 s): how long to wait for the coordinator and for every
    process to join. Raises ValueError in one line when there is no cluster to join or the
    coordinator does not answer. When the processes do not all join in time, JAX aborts the
    process from C++ (a stack trace, no exception to catch): a watchdog ends it first, with one
    line on stderr and exit status 2.
    """
    if jax.distributed.is_initialized():
        return
    if timeout is None:
        timeout = _env_int("JAXANOM_DISTRIBUTED_TIMEOUT", 1) or 300
    elif int(timeout) < 1:
        raise ValueError(f"timeout: expected seconds >= 1, got {timeout}")
    timeout = int(timeout)
    num_processes, process_id = _env_int("JAX_NUM_PROCESSES", 1), _env_int("JAX_PROCESS_ID", 0)
    if None not in (num_processes, process_id) and process_id >= num_processes:
        raise ValueError(f"JAX_PROCESS_ID: expected an id below JAX_NUM_PROCESSES={num_processes}, got {process_id}")
    address = os.environ.get("JAX_COORDINATOR_ADDRESS")
    if address:
        host, port = _host_port(address)  # every process: JAX itself fails on a malformed one with a traceback
        if process_id:
            _wait_for(address, host, port, timeout)
    previous = jax.config.jax_cpu_collectives_implementation
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU hosts; GPUs use NCCL
    watchdog = threading.Timer(timeout, _give_up, args=(address, timeout))
    watchdog.daemon = True
    watchdog.start()
    try:  # JAX's own deadline comes later than the watchdog's, so its abort never wins the race
        jax.distributed.initialize(num_processes=num_processes, process_id=process_id,
                                   initialization_timeout=timeout + _ABORT_GRACE_S)
    except (ValueError, RuntimeError) as error:
        jax.config.update("jax_cpu_collectives_implementation", previous)
        raise ValueError(f"distributed: cannot join a multi-host run ({str(error).strip().splitlines()[0]}): start one "
                         "process per host under SLURM, Open MPI or a TPU pod, or set JAX_COORDINATOR_ADDRESS "
                         "(host:port), JAX_NUM_PROCESSES and JAX_PROCESS_ID") from None
    finally:
        watchdog.cancel()


_ABORT_GRACE_S = 30


def _env_int(name: str, lowest: int) -> int | None:
    """The integer in environment variable ``name`` (None where unset); ValueError naming it otherwise."""
    text = os.environ.get(name, "").strip()
    if not text:
        return None
    if not text.isdigit() or int(text) < lowest:
        raise ValueError(f"{name}: expected an integer >= {lowest}, got {text!r}")
    return int(text)


def _give_up(address: str | None, timeout: int) -> None:
    """End the process with one line: not every process joined the run within ``timeout`` seconds."""
    where = f" at {address}" if address else ""
    sys.stderr.write(f"jaxanom: error: distributed: not every process joined the run{where} within {timeout} s; "
                     "start one process per host with the same JAX_COORDINATOR_ADDRESS and JAX_NUM_PROCESSES "
                     "(JAXANOM_DISTRIBUTED_TIMEOUT sets the wait)\n")
    sys.stderr.flush()
    os._exit(2)


def _host_port(address: str) -> tuple[str, int]:
    """``(host, port)`` of ``JAX_COORDINATOR_ADDRESS`` (``host:port``, ``[ipv6]:port``); ValueError naming it."""
    host, _, port = address.rpartition(":")
    if not host.strip("[]") or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"JAX_COORDINATOR_ADDRESS: expected host:port with a port from 1 to 65535, got {address!r}")
    return host.strip("[]"), int(port)


def _wait_for(address: str, host: str, port: int, timeout: int) -> None:
    """Until ``timeout`` seconds pass, try to reach the coordinator at ``host``:``port``; ValueError if it never
    answers."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            socket.create_connection((host, port), timeout=min(5.0, timeout)).close()
            return
        except OSError as error:
            if time.monotonic() >= deadline:
                raise ValueError(f"distributed: the coordinator {address} did not answer within {timeout} s "
                                 f"({error.strerror or error}); is process 0 running, and the address right? "
                                 "(JAXANOM_DISTRIBUTED_TIMEOUT sets the wait)") from None
            time.sleep(min(1.0, max(0.0, deadline - time.monotonic())))


def make_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D mesh named "data" over ``devices`` (default: all devices of all processes)."""
    devices = jax.devices() if devices is None else list(devices)
    return jax.make_mesh((len(devices),), (DATA,), axis_types=(AxisType.Auto,), devices=devices)


def replicated(mesh: Mesh) -> NamedSharding:
    """Every device holds the whole array."""
    return NamedSharding(mesh, P())


def batch_sharding(mesh: Mesh) -> NamedSharding:
    """Leading (batch) axis split over the "data" axis."""
    return NamedSharding(mesh, P(DATA))


def global_batch(local_batch: dict, mesh: Mesh) -> dict:
    """Assemble this process's share of a batch (dict of host arrays) into global arrays (``jax.Array``).

    The local batch size must divide evenly over this process's devices in the mesh.
    """
    sharding = batch_sharding(mesh)
    local_devices = len(mesh.local_devices)
    out = {}
    for name, value in local_batch.items():
        value = np.asarray(value)
        if value.ndim == 0 or value.shape[0] % local_devices:
            raise ValueError(
                f"batch[{name!r}]: expected a leading batch axis divisible by the {local_devices} "
                f"local devices, got shape {value.shape}")
        out[name] = jax.make_array_from_process_local_data(sharding, value)
    return out
