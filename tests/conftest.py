"""Test set-up: 4 simulated CPU devices (configured before JAX starts a backend), real sample data."""
import os
from pathlib import Path

# The suite is bound by XLA compile time, not by run time: LLVM's optimisation passes off (level 0)
# compile 2-3x faster. Numerics are unchanged (fast-math is off at every level). Set before JAX
# starts a backend; subprocesses started by tests inherit it.
os.environ["XLA_FLAGS"] = " ".join([os.environ.get("XLA_FLAGS", ""), "--xla_backend_optimization_level=0"]).strip()

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
