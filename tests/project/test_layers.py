"""The three layers of README.md, read from the source: library <- application (``jaxanom.app``) <- ``jaxanom.cli``;
the papers packaged whole (no switch on their names elsewhere) and the README layout naming every package.

Every ``import`` counts, also those inside functions: a lazy upward import is still an upward
dependency. Library modules import neither ``jaxanom.app`` nor ``jaxanom.cli``; application
modules do not import ``jaxanom.cli``; and no group of modules imports itself in a cycle. The
command line reaches jaxanom only through ``jaxanom.app`` and the error types, and the demos
are leaves: nothing builds on them but the ``demo`` command that runs them (tests may import them).
"""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "jaxanom"
REPOSITORY = PACKAGE.parent
DEMO_RUNNER = "jaxanom.app.commands.demo"  # the one module that imports the demos: it runs them


def module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path, modules: set[str]) -> set[str]:
    """The jaxanom modules ``path`` imports (``from jaxanom import sml`` names ``jaxanom.sml``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            for alias in node.names:
                submodule = f"{node.module}.{alias.name}"
                found.add(submodule if submodule in modules else node.module)
    return {name for name in found if name in modules}


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    files = {module_name(path, root): path for path in root.rglob("*.py")}
    return {name: imported(path, set(files)) - {name} for name, path in files.items()}


def layer(name: str) -> int:
    """0 library, 1 application, 2 command line."""
    return 2 if name.startswith("jaxanom.cli") else 1 if name.startswith("jaxanom.app") else 0


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    return sorted(f"{a} -> {b}" for a, deps in graph.items() for b in deps if layer(b) > layer(a))


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    edges = graph
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in edges[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    return found


def test_no_layer_imports_a_layer_above_it():
    assert upward_imports(import_graph()) == []


def test_no_import_cycles():
    assert cycles(import_graph()) == []


def test_the_application_layer_exists_and_the_cli_only_dispatches_to_it():
    graph = import_graph()
    assert any(layer(name) == 1 for name in graph)
    assert any(layer(b) == 1 for a, deps in graph.items() if layer(a) == 2 for b in deps)


@pytest.fixture
def fake_package(tmp_path):
    """A package tree named jaxanom with one upward import and one cycle, to show the checks can fail."""
    root = tmp_path / "jaxanom"
    for name, text in {"__init__.py": "", "scores.py": "from jaxanom.app import demo\n",
                       "app/__init__.py": "", "app/demo.py": "import jaxanom.cli.main\n",
                       "cli/__init__.py": "", "cli/main.py": "from jaxanom import scores\n",
                       "a.py": "def f():\n    from jaxanom import b\n", "b.py": "import jaxanom.a\n"}.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def test_checks_find_an_upward_import_and_a_cycle(fake_package):
    graph = import_graph(fake_package)
    assert upward_imports(graph) == ["jaxanom.app.demo -> jaxanom.cli.main", "jaxanom.scores -> jaxanom.app.demo"]
    assert cycles(graph) == [["jaxanom.a", "jaxanom.b"],
                             ["jaxanom.app.demo", "jaxanom.cli.main", "jaxanom.scores"]]


def files_naming_shared_notes(root: Path = PACKAGE) -> list[str]:
    """Files of the package that point outside the repository, at ``../shared``: a clone has no such
    folder, so what the code relies on from those notes is written in ``docs/papers/`` instead."""
    return sorted(str(path.relative_to(root)) for path in root.rglob("*") if path.is_file()
                  and path.suffix in {".py", ".md", ".txt", ".json", ".toml", ".cfg"}
                  and "../shared" in path.read_text(errors="replace"))


def test_no_package_file_names_the_shared_folder_beside_the_repository():
    assert files_naming_shared_notes() == []


def test_the_shared_folder_check_finds_a_docstring_that_names_it(fake_package):
    (fake_package / "app" / "demo.py").write_text('"""See ``../shared/METHODS.md`` section 1."""\n')
    assert files_naming_shared_notes(fake_package) == ["app/demo.py"]


def cli_imports_beyond_the_app(graph: dict[str, set[str]]) -> list[str]:
    """``cli -> module`` for each jaxanom module a ``jaxanom.cli`` module imports other than
    ``jaxanom.app`` (and below), ``jaxanom.errors`` and ``jaxanom.cli`` itself."""
    allowed = ("jaxanom.app", "jaxanom.errors", "jaxanom.cli")
    return sorted(f"{a} -> {b}" for a, deps in graph.items() if layer(a) == 2 for b in deps
                  if not any(b == p or b.startswith(p + ".") for p in allowed) and b != "jaxanom")


def imports_of_demos(files: dict[str, Path]) -> list[str]:
    """``module -> demo`` for each module of ``files`` ({name: path}) that imports ``jaxanom.app.demos``
    or one of its modules, but the demos themselves and the demo command."""
    found = []
    for name, path in files.items():
        if name.startswith("jaxanom.app.demos") or name == DEMO_RUNNER:
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
            else:
                continue
            found += [f"{name} -> {t}" for t in targets if t == "jaxanom.app.demos" or t.startswith("jaxanom.app.demos.")
                      and t.count(".") == 3]
    return sorted(set(found))


def source_files(root: Path = REPOSITORY) -> dict[str, Path]:
    """The modules of the package, the experiments and the benchmarks (not the tests)."""
    return {module_name(path, root / folder): path
            for folder in ("jaxanom", "experiments", "benchmarks") for path in (root / folder).rglob("*.py")}


def test_the_cli_imports_only_the_application_and_the_errors():
    assert cli_imports_beyond_the_app(import_graph()) == []


def test_nothing_but_the_demo_command_imports_a_demo():
    assert imports_of_demos(source_files()) == []


def test_the_cli_and_demo_checks_find_what_they_forbid(fake_package):
    (fake_package / "cli" / "run.py").write_text("from jaxanom.app import demo\nfrom jaxanom.errors import InputError\n"
                                                 "def f():\n    from jaxanom.sml import stats\n")
    (fake_package / "errors.py").write_text("")
    (fake_package / "sml").mkdir()
    (fake_package / "sml" / "__init__.py").write_text("")
    (fake_package / "sml" / "stats.py").write_text("")
    assert cli_imports_beyond_the_app(import_graph(fake_package)) == ["jaxanom.cli.main -> jaxanom.scores",
                                                                      "jaxanom.cli.run -> jaxanom.sml.stats"]
    (fake_package / "app" / "demos").mkdir()
    (fake_package / "app" / "demos" / "__init__.py").write_text("")
    (fake_package / "app" / "demos" / "mmf.py").write_text("from jaxanom.app import demo\n")
    (fake_package / "app" / "experiment.py").write_text("def f():\n    from jaxanom.app.demos.mmf import Config\n")
    files = {module_name(path, fake_package): path for path in fake_package.rglob("*.py")}
    assert imports_of_demos(files) == ["jaxanom.app.experiment -> jaxanom.app.demos.mmf"]


# Papers packaged whole: their names are registered from their package and switched on nowhere else.
PAPER_PACKAGES = ("cudam", "msaam")


def paper_names_outside_their_packages(root: Path = PACKAGE) -> list[str]:
    """``file:line name`` for each string literal equal to a paper package's name in code outside
    that package (docstrings and the paper demos of ``app/demos``, which configure a paper's run as
    a user does, aside): a switch on a paper that its package's registrations should make."""
    found = []
    for path in sorted(root.rglob("*.py")):
        relative = path.relative_to(root)
        if relative.parts[:2] == ("app", "demos"):
            continue
        tree = ast.parse(path.read_text(), str(path))
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)
                      and isinstance(node.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and node.value in PAPER_PACKAGES and id(node) not in docstrings
                    and relative.parts[0] != node.value):
                found.append(f"{relative}:{node.lineno} {node.value}")
    return found


def test_no_module_switches_on_a_paper_outside_its_package():
    assert paper_names_outside_their_packages() == []


def test_the_paper_name_check_finds_a_switch(fake_package):
    (fake_package / "models.py").write_text('"""Say "cudam" here."""\ndef f(a):\n    return a == "cudam"\n')
    (fake_package / "cudam").mkdir()
    (fake_package / "cudam" / "attention.py").write_text('NAME = "cudam"\n')
    assert paper_names_outside_their_packages(fake_package) == ["models.py:3 cudam"]


def readme_layout_omissions(readme: str, root: Path = PACKAGE) -> list[str]:
    """The subpackages of ``root`` that the README's layout block (the first ``text`` block after
    "## Three layers") does not name as ``name/``."""
    block = readme.split("## Three layers", 1)[1].split("```text", 1)[1].split("```", 1)[0]
    packages = sorted(p.parent.name for p in root.glob("*/__init__.py"))
    return [name for name in packages if f"{name}/" not in block]


def test_the_readme_layout_names_every_package():
    assert readme_layout_omissions((REPOSITORY / "README.md").read_text()) == []


def test_the_layout_check_finds_a_missing_package(fake_package):
    readme = "## Three layers\n\n```text\njaxanom/\n  app/ cli/\n```\n"
    assert readme_layout_omissions(readme, fake_package) == []
    (fake_package / "sml").mkdir()
    (fake_package / "sml" / "__init__.py").write_text("")
    assert readme_layout_omissions(readme, fake_package) == ["sml"]
