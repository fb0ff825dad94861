"""The README's Python examples run as written; CI runs the README's test commands."""
from pathlib import Path

import pytest

from doc_examples import code_blocks

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
EXAMPLES = code_blocks(README.read_text(), "python")


def test_readme_has_examples():
    assert len(EXAMPLES) >= 2


@pytest.mark.parametrize("index", range(len(EXAMPLES)))
def test_readme_example_runs(index, capsys):
    exec(compile(EXAMPLES[index], f"README example {index}", "exec"), {})


def test_ci_runs_every_test_command_of_the_readme():
    """Both tiers (the suite, then ``-m end_to_end``), as written, each on a line of its own."""
    commands = [line for block in code_blocks(README.read_text(), "bash")
                for line in block.splitlines() if "pytest" in line]
    assert any(line.endswith("-m end_to_end") for line in commands) and len(commands) == 2
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert all(command in ci_lines for command in commands)
