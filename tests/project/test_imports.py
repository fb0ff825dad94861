"""The core library and the benchmarks import on a machine without grain or tensorboardX.

Machines with accelerators may have neither: a subprocess blocks both imports and loads every
module that does not need them.
"""
import subprocess
import sys

BLOCK = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("grain", "tensorboardX"):
            raise ModuleNotFoundError(name)
sys.meta_path.insert(0, Block())
"""

MODULES = ["jaxanom", "jaxanom.scores", "jaxanom.sml", "jaxanom.metrics", "jaxanom.models", "jaxanom.nn",
           "jaxanom.losses", "jaxanom.train.step", "jaxanom.train.segmenter", "jaxanom.method_registry", "jaxanom.app.scoring", "jaxanom.cli",
           "benchmarks.__main__", "benchmarks.bench_data", "benchmarks.bench_losses", "benchmarks.bench_metrics",
           "benchmarks.bench_models", "benchmarks.bench_scaling", "benchmarks.bench_sml", "benchmarks.bench_espnet"]


def test_imports_without_grain_and_tensorboardx():
    code = BLOCK + "".join(f"import {name}\n" for name in MODULES) + "import grain\n"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 1 and result.stderr.strip().endswith("ModuleNotFoundError: grain"), result.stderr
