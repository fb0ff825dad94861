"""Data parallelism: one mesh axis "data" over every device of every host.

Parameters and optimizer state are replicated (``P()``), batches are split along their first
axis (``P("data")``); XLA inserts the gradient all-reduce, and BatchNorm statistics are those of
the global batch. The same code runs on one CPU, eight GPUs or a multi-host pod. The mesh axis
is ``AxisType.Auto`` (sharding propagated by the compiler), so model code needs no sharding
annotations.
"""
from __future__ import annotations

from typing import Sequence

import jax
import numpy as np
from jax.sharding import AxisType, Mesh, NamedSharding, PartitionSpec as P

DATA = "data"


def initialize_distributed() -> None:
    """Join a multi-host run (``jax.distributed.initialize``); call before any other JAX work.

    The coordinator, process count and id are detected from the cluster environment
    (TPU pods, SLURM, Open MPI, ...), as ``jax.distributed.initialize`` documents. A second call
    is a no-op, so a command may join early and the train loop still asks.
    """
    if not jax.distributed.is_initialized():
        jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU hosts; GPUs use NCCL
        jax.distributed.initialize()


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
