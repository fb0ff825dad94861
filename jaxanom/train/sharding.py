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
    ``$JAXANOM_DISTRIBUTED_TIMEOUT`` or 300 s): how long to wait for the coordinator. Raises
    ValueError in one line when there is no cluster to join, or the coordinator does not answer
    (JAX itself would wait in silence, then abort the process).
    """
    if jax.distributed.is_initialized():
        return
    timeout = int(os.environ.get("JAXANOM_DISTRIBUTED_TIMEOUT", 300)) if timeout is None else int(timeout)
    address, index = os.environ.get("JAX_COORDINATOR_ADDRESS"), os.environ.get("JAX_PROCESS_ID")
    if address and index not in (None, "0"):
        _wait_for(address, timeout)
    previous = jax.config.jax_cpu_collectives_implementation
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU hosts; GPUs use NCCL
    try:
        jax.distributed.initialize(initialization_timeout=timeout)
    except (ValueError, RuntimeError) as error:
        jax.config.update("jax_cpu_collectives_implementation", previous)
        raise ValueError(f"distributed: cannot join a multi-host run ({str(error).strip().splitlines()[0]}): start one "
                         "process per host under SLURM, Open MPI or a TPU pod, or set JAX_COORDINATOR_ADDRESS "
                         "(host:port), JAX_NUM_PROCESSES and JAX_PROCESS_ID") from None


def _wait_for(address: str, timeout: int) -> None:
    """Until ``timeout`` seconds pass, try to reach the coordinator at ``host:port``; ValueError if it never answers."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"JAX_COORDINATOR_ADDRESS: expected host:port, got {address!r}")
    deadline = time.monotonic() + timeout
    while True:
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=min(5.0, timeout)).close()
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
    """Assemble this process's share of a batch (dict of host arrays) into global ``jax.Array``s.

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
