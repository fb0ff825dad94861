"""The checkout holds only what belongs in it: tools write their results elsewhere."""
import importlib.util
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_mutation_results_go_outside_the_checkout():
    spec = importlib.util.spec_from_file_location("mutate", ROOT / "tools" / "mutate.py")
    mutate = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mutate)
    assert ROOT not in mutate.DEFAULT_OUT.resolve().parents
    tracked = subprocess.run(["git", "ls-files", "mutants.jsonl"], cwd=ROOT, capture_output=True, text=True).stdout
    assert tracked == ""
