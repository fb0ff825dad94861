"""The API reference (``docs/api``, Sphinx autodoc + napoleon) builds from the docstrings with
warnings as errors, as the README says to build it: a docstring that is not valid reStructuredText
(an unclosed ``literal``, ``|x|`` read as a substitution, a list without a blank line before it)
fails here."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_api_reference_builds_with_warnings_as_errors(tmp_path):
    html = tmp_path / "html"
    # -W: every warning is an error (Sphinx >= 8.1 reports them all before failing)
    command = [sys.executable, "-m", "sphinx", "-W", "-q", "-b", "html",
               "-d", str(tmp_path / "doctrees"), str(ROOT / "docs" / "api"), str(html)]
    result = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-6000:]
    pages = {page.stem for page in (html / "modules").glob("*.html")}
    # the library, the command functions and the training config; not the application's internals nor the cli
    assert {"jaxanom.method_registry", "jaxanom.objectives", "jaxanom.metrics.evaluator", "jaxanom.sml.score",
            "jaxanom.app.commands.score", "jaxanom.app.experiment"} <= pages
    public_app = ("jaxanom.app.commands", "jaxanom.app.experiment")
    assert not {page for page in pages if page.startswith(("jaxanom.cli", "jaxanom._", "jaxanom.app"))
                and not page.startswith(public_app)}
    assert "standardized_max_logit" in (html / "modules" / "jaxanom.sml.score.html").read_text()
