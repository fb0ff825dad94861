"""Test set-up: 4 simulated CPU devices (configured before JAX starts a backend), real sample data."""
import os
import shutil
import tempfile
from pathlib import Path

# The suite is bound by XLA compile time. A persistent compilation cache for this session (an
# empty folder each run) lets tests that build the same computation, in this process, in the
# subprocesses they start or in the other pytest-xdist workers (they inherit this environment
# from the controller, which loads this file first), compile it once. A size limit turns on
# JAX's file lock around each entry, so one worker never reads another's half-written entry.
# Set before JAX reads its configuration.
_XLA_CACHE = None if "JAX_COMPILATION_CACHE_DIR" in os.environ else tempfile.mkdtemp(prefix="jaxanom-tests-xla-")
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _XLA_CACHE or "")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")
os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(8 << 30))
# The networks here are tiny, so XLA's compile time dwarfs run time: backend optimisation level 0
# (XLA's default is 3) roughly halves the CPU time of a network's first train step. Float32
# results move within rounding (no fused multiply-adds), which the tests' tolerances allow
# (docs/decisions/test-speed.md). Subprocesses and xdist workers inherit it.
OPT_FLAG = "--xla_backend_optimization_level=0"
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {OPT_FLAG}".strip()

import jax  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

jax.config.update("jax_num_cpu_devices", 4)
jax.config.update("jax_platforms", "cpu")

# CI runs the same property examples every time (a failure there is reproducible); locally they vary.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

# ../shared/realdata beside the repository (as CI clones it), or JAXANOM_REALDATA.
REALDATA = Path(os.environ.get("JAXANOM_REALDATA", Path(__file__).resolve().parents[2] / "shared" / "realdata"))


@pytest.fixture(scope="session")
def road_anomaly_sample() -> Path:
    """The folder of the six real Road Anomaly frames; skips (with the path) where it is absent."""
    root = REALDATA / "RoadAnomaly_sample"
    if not root.is_dir():
        pytest.skip(f"real Road Anomaly sample not found at {root} (set JAXANOM_REALDATA)")
    return root


# The files that take longest (most of it compiling), longest first: the end-to-end tier's four
# (`-m end_to_end`), then the default suite's. pytest-xdist's loadfile hands each worker a whole
# file at a time in collection order (``--no-loadscope-reorder`` in pyproject keeps this order
# instead of sorting by test count), so these start first and the short files fill in around them;
# a long file left to the end would keep one worker busy while the other idles.
LONGEST_FIRST = ("test_mmf_demo.py", "test_experiments_offroad.py", "test_mmf_table2.py", "test_experiments.py",
                 "test_offroad_crf.py", "test_cli.py", "test_weights.py", "test_distributed.py", "test_predict.py",
                 "test_offroad_pipeline.py", "test_train_segmenter.py", "test_mmf_spade.py", "test_nn_afc_rgbd.py",
                 "test_mixture.py", "test_nn_spade_dissimilarity.py", "test_weights_cli.py", "test_superpixels.py",
                 "test_mmf_postprocess.py")


def pytest_collection_modifyitems(items):
    """Run the files of ``LONGEST_FIRST`` first, in its order; the rest keep pytest's order."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def pytest_unconfigure(config):
    """Remove this session's compilation cache (not one the caller named)."""
    if _XLA_CACHE:
        shutil.rmtree(_XLA_CACHE, ignore_errors=True)
