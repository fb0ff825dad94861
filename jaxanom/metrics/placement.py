"""Pooled metrics need every pixel in one place: gather sharded inputs onto one device."""
from __future__ import annotations

import jax


def on_one_device(array: jax.Array) -> jax.Array:
    """``array`` itself if it lives on one device, else a copy on the lowest-id device of its
    sharding (also dropping explicit-mesh axis types, which a pooled sort or bincount cannot
    take). Multi-host arrays are not supported: pool their host-local parts instead."""
    devices = array.devices()
    if len(devices) == 1:
        return array
    return jax.device_put(array, jax.sharding.SingleDeviceSharding(min(devices, key=lambda d: d.id)))
