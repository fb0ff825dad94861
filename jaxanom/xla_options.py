"""XLA compiler options for the convolutional networks: ``jax.jit(fn, compiler_options=conv_compiler_options())``.

On the CPU, the XLA bundled with jaxlib 0.10 hands every convolution to YNNPACK (an
``__ynn_fusion`` per convolution); for DeepLabV3+ R101 that is about twice as slow, forward and
backward, as XLA's own (Eigen) convolutions and 1x1 convolutions as dot products (measurements:
docs/decisions/cpu-speed.md). ``xla_cpu_experimental_ynn_fusion_type=""`` turns the YNNPACK
rewrite off for one jitted function only, not for the process (``XLA_FLAGS`` would). Results
change within float32 rounding (a different summation order). On other backends: no options.
"""
from __future__ import annotations

import jax

_CPU = {"xla_cpu_experimental_ynn_fusion_type": ""}


def conv_compiler_options(backend: str | None = None) -> dict[str, str]:
    """``compiler_options`` for ``jax.jit`` of a network's forward or train step on ``backend``
    (default: JAX's default backend): the CPU options above, ``{}`` elsewhere."""
    return dict(_CPU) if (backend or jax.default_backend()) == "cpu" else {}
