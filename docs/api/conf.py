"""Sphinx configuration of jaxanom's API reference, generated from the docstrings.

Build: ``python -m sphinx -W -b html docs/api docs/api/_build`` (``tests/project/test_api_docs.py``
builds it with warnings as errors), then open ``docs/api/_build/index.html``. The page of each
public module is written here, into ``modules/`` (not committed), on every build: a new module
is covered without editing anything.

Sphinx rather than pdoc: the docstrings are reStructuredText (``literals``, lists, ``::`` blocks),
which Sphinx parses and checks (docutils' warnings, errors here), with napoleon for the few
Google-style ``Args:`` / ``Attributes:`` sections; pdoc would render them as Markdown without checking their markup.
"""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

project = "jaxanom"
extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon"]
exclude_patterns = ["_build"]
html_theme = "alabaster"
smartquotes = False  # the docstrings' quotes and primes (U_b', "first") are code-like: kept as written
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
napoleon_numpy_docstring = False  # the docstrings are reST prose; a few Google-style "Args:" sections
napoleon_use_ivar = True  # "Attributes:" as fields of the class, not a second description of its dataclass fields

# Of the application layer only what a Python user calls: one function per command and the training
# run's config (``--config`` files build an ``Experiment``). The rest of ``jaxanom.app`` and all of
# ``jaxanom.cli`` are internals; ``_private`` modules are left out everywhere.
APP_PUBLIC = ("jaxanom.app.commands", "jaxanom.app.experiment")


def public_modules() -> list[str]:
    """Dotted names of the modules the reference covers, sorted (read from the files: nothing imported)."""
    package = ROOT / "jaxanom"
    names = []
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        parts = parts[:-1] if parts[-1] == "__init__" else parts
        name = ".".join(parts)
        if any(p.startswith("_") for p in parts) or name == "jaxanom.cli" or name.startswith("jaxanom.cli."):
            continue
        if name == "jaxanom.app" or (name.startswith("jaxanom.app.") and not name.startswith(APP_PUBLIC)):
            continue
        names.append(name)
    return sorted(names)


def write_module_pages() -> None:
    """One page per public module (``modules/<name>.rst``), rewritten only where it changed."""
    folder = HERE / "modules"
    folder.mkdir(exist_ok=True)
    pages = {f"{name}.rst": f"{name}\n{'=' * len(name)}\n\n.. automodule:: {name}\n" for name in public_modules()}
    for stale in set(p.name for p in folder.glob("*.rst")) - set(pages):
        (folder / stale).unlink()
    for file, text in pages.items():
        if not (folder / file).is_file() or (folder / file).read_text() != text:
            (folder / file).write_text(text)


write_module_pages()
