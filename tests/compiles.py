"""The XLA compiles a call makes, read from ``jax.monitoring`` (for tests that guard against compiles)."""
from __future__ import annotations

from typing import Any, Callable

import jax.monitoring


def compiled_during(fn: Callable[[], Any]) -> tuple[Any, list[str]]:
    """``(fn(), names of the functions XLA compiled during the call)``."""
    names: list[str] = []

    def listener(event, _, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            names.append(str(kwargs.get("fun_name")))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        return fn(), names
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
