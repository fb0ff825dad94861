"""XLA options for the convolutional networks: ``jax.jit(fn, compiler_options=conv_compiler_options(),
donate_argnums=state_donation())``.

On the CPU, the XLA bundled with jaxlib 0.10 hands every convolution to YNNPACK (an
``__ynn_fusion`` per convolution); for DeepLabV3+ R101 that is about twice as slow, forward and
backward, as XLA's own (Eigen) convolutions and 1x1 convolutions as dot products (measurements:
docs/decisions/cpu-speed.md). ``xla_cpu_experimental_ynn_fusion_type=""`` turns the YNNPACK
rewrite off for one jitted function only, not for the process (``XLA_FLAGS`` would). Results
change within float32 rounding (a different summation order). On other backends: no options.

Donating the train state lets XLA update it in place; on the CPU that costs more than it saves:
XLA copies each donated parameter before its update (it cannot prove the update comes after the
backward pass's reads of the same weights), about 15% of DeepLabV3+ R101's training step, so on
the CPU the state is not donated (one more copy of the state in memory during a step).
"""
from __future__ import annotations

import jax

_CPU = {"xla_cpu_experimental_ynn_fusion_type": ""}


def conv_compiler_options(backend: str | None = None) -> dict[str, str]:
    """``compiler_options`` for ``jax.jit`` of a network's forward or train step on ``backend``
    (default: JAX's default backend): the CPU options above, ``{}`` elsewhere."""
    return dict(_CPU) if (backend or jax.default_backend()) == "cpu" else {}


def state_donation(backend: str | None = None) -> tuple[int, ...]:
    """``donate_argnums`` for a jitted train step whose first argument is the state: ``(0,)``,
    or ``()`` on the CPU (above)."""
    return () if (backend or jax.default_backend()) == "cpu" else (0,)
