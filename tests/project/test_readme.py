"""The README's Python examples run as written; CI runs the README's test commands."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
EXAMPLES = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def test_readme_has_examples():
    assert len(EXAMPLES) >= 2


@pytest.mark.parametrize("index", range(len(EXAMPLES)))
def test_readme_example_runs(index, capsys):
    exec(compile(EXAMPLES[index], f"README example {index}", "exec"), {})


def test_ci_runs_every_test_command_of_the_readme():
    """Both tiers (the suite, then ``-m end_to_end``), as written, each on a line of its own."""
    commands = [line for block in re.findall(r"```bash\n(.*?)```", README.read_text(), re.S)
                for line in block.splitlines() if "pytest" in line]
    assert any(line.endswith("-m end_to_end") for line in commands) and len(commands) == 2
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert all(command in ci_lines for command in commands)
