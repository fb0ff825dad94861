"""jaxanom.builtins: the one list of modules that register jaxanom's own plug-ins, first in every registry."""
import os
import subprocess
import sys
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[1]


def test_the_names_list_jaxanoms_own_first_in_the_lists_order_whatever_was_imported_first():
    """A fresh interpreter that imports MSAAM's objective and a plug-in before anything else still
    lists cross_entropy, cudam, msaam first (the order of ``MODULES``), then the plug-in."""
    script = ("import dataclasses\n"
              "from jaxanom.msaam.objective import MSAAM\n"
              "from jaxanom.objectives import Objective, objective_names, register\n"
              "@register\n@dataclasses.dataclass(frozen=True)\n"
              "class Focal(Objective):\n    name: str = dataclasses.field(default='focal', init=False)\n"
              "from jaxanom.models.attention import attention_names\n"
              "print(objective_names(), attention_names())\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPOSITORY), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, check=True).stdout
    assert out.strip() == "('cross_entropy', 'cudam', 'msaam', 'focal') ('cudam', 'msaam')"


def test_each_registry_loads_the_one_list():
    from jaxanom import builtins
    from jaxanom.method_registry import METHODS
    from jaxanom.metrics.evaluator import EVALUATORS
    from jaxanom.models.attention import ATTENTION_MODULES
    from jaxanom.objectives import OBJECTIVES
    from jaxanom.protocols import PROTOCOLS

    registries = (METHODS, OBJECTIVES, ATTENTION_MODULES, EVALUATORS, PROTOCOLS)
    assert all(tuple(r._builtins()) == builtins.MODULES for r in registries)
    origins = {origin for r in registries for name in r.names() for origin in [r.origin(name)]}
    assert set(builtins.MODULES) <= origins  # each listed module registers something

