#!/usr/bin/env bash
# The whole GPU measurement in one command: every benchmark at its GPU sizes, against its peers
# (PyTorch on CUDA, scikit-learn), each result checked against the CPU result, in under 10 minutes.
#
#   bash benchmarks/gpu.sh [RESULTS_FILE [--only NAME ...]]
#
# RESULTS_FILE defaults to $OUT/RESULTS.md on the device machine (where only $OUT comes back),
# else benchmarks/RESULTS-gpu.md; it is rewritten after each benchmark, so a run stopped at
# GPU_BENCH_TIMEOUT seconds (default 590) keeps what it measured. Arguments after RESULTS_FILE go
# to `python -m benchmarks`. grain is not needed: bench_data reports itself not run without it.
set -euo pipefail
cd "$(dirname "$0")/.."
export PYTHONPATH=.${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_PREALLOCATE=false  # the PyTorch peers share the GPU with JAX in one process
python3 -c "import jax, sys; sys.exit(0 if jax.default_backend() == 'gpu' else f'no GPU: {jax.devices()}')"
results=${1:-${OUT:+$OUT/RESULTS.md}}
timeout "${GPU_BENCH_TIMEOUT:-590}" python3 -m benchmarks --write --results "${results:-benchmarks/RESULTS-gpu.md}" "${@:2}"
