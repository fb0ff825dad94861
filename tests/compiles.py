"""The XLA compiles a call makes, read from ``jax.monitoring`` (for tests that guard against compiles)."""
from __future__ import annotations

from typing import Any, Callable

import jax.monitoring

# Lowering, not the backend compile: a computation missing from the in-memory caches is lowered once and
# then compiled, or read from the persistent compilation cache the suite keeps (no backend compile event
# then). Counting lowerings counts both, so a guard holds whatever another test compiled before.
_LOWERED = "/jax/core/compile/jaxpr_to_mlir_module_duration"


def compiled_during(fn: Callable[[], Any]) -> tuple[Any, list[str]]:
    """``(fn(), names of the functions compiled, or read from the persistent cache, during the call)``."""
    names: list[str] = []

    def listener(event, _, **kwargs):
        if event == _LOWERED:
            names.append(str(kwargs.get("fun_name")))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        return fn(), names
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
