"""Every name the code uses is defined: a static check, because a typo or a lost definition in a
path the tests do not run (a real-data experiment, a benchmark) otherwise fails only when a user runs it."""
from pathlib import Path

import pytest
from pyflakes import api, messages, reporter

ROOT = Path(__file__).resolve().parents[2]
UNDEFINED = (messages.UndefinedName, messages.UndefinedLocal, messages.UndefinedExport)


class _Collect(reporter.Reporter):
    def __init__(self):
        self.found: list[str] = []

    def flake(self, message):
        if isinstance(message, UNDEFINED):
            self.found.append(str(message))

    def syntaxError(self, filename, msg, lineno, offset, text):
        self.found.append(f"{filename}:{lineno}: {msg}")

    def unexpectedError(self, filename, msg):
        self.found.append(f"{filename}: {msg}")


@pytest.mark.parametrize("folder", ["jaxanom", "experiments", "benchmarks", "tests"])
def test_every_name_used_is_defined(folder):
    collect = _Collect()
    api.checkRecursive([str(ROOT / folder)], collect)
    assert collect.found == []
