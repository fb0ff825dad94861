"""`import jaxanom.sml` / `jaxanom.scores` stay light: no torch, grain, matplotlib, tensorboardX."""
import subprocess
import sys
from pathlib import Path


def test_scoring_modules_import_nothing_heavy():
    code = (
        "import sys, jaxanom.sml, jaxanom.scores; "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'grain', 'matplotlib', 'tensorboardX'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.stdout.strip() == "[]"
