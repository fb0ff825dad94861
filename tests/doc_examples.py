"""A Markdown page's examples, run as written: what ``tests/project/test_readme.py`` and
``tests/project/test_extending.py`` share.

``code_blocks(text, language)``: the page's fenced blocks of that language, in order.
``run_page(page, folder)`` (also ``python tests/doc_examples.py PAGE FOLDER``, as the tests run
it: in a process of its own, so what a page registers stays there) runs a page's ```python and
```bash blocks in page order, in ``folder`` (the working directory, first on ``sys.path``):

- a python block whose first line is ``# file: PATH`` is written to ``PATH`` (a plug-in's module,
  a config file);
- the other python blocks run in one namespace, each seeing what the ones before it defined;
- each line of a bash block (``\\``-continued lines joined, ``#`` comments dropped) is either
  ``export PYTHONPATH=$PWD`` (which ``folder`` on ``sys.path`` stands for) or a ``jaxanom`` command,
  run through ``jaxanom.cli.main``, which must return 0; any other line fails, so nothing the page
  shows goes unrun.
"""
import os
import re
import shlex
import sys
from pathlib import Path

FENCE = re.compile(r"```(\w+)\n(.*?)```", re.S)
FILE = re.compile(r"# file: (\S+)\n")


def code_blocks(text: str, language: str) -> list[str]:
    return [body for lang, body in FENCE.findall(text) if lang == language]


def shell_lines(block: str) -> list[list[str]]:
    """The commands of a bash block, split as the shell does."""
    return [words for line in block.replace("\\\n", " ").splitlines() if (words := shlex.split(line, comments=True))]


def run_page(page, folder) -> None:
    from jaxanom.cli import main

    name, text, folder = Path(page).name, Path(page).read_text(), Path(folder).resolve()
    os.chdir(folder)
    sys.path.insert(0, str(folder))
    namespace = {"__name__": "__main__"}
    for index, (language, body) in enumerate(FENCE.findall(text)):
        if language == "python" and (file := FILE.match(body)):
            (folder / file.group(1)).parent.mkdir(parents=True, exist_ok=True)
            (folder / file.group(1)).write_text(body)
        elif language == "python":
            exec(compile(body, f"{name} block {index}", "exec"), namespace)
        elif language == "bash":
            for words in shell_lines(body):
                if words == ["export", "PYTHONPATH=$PWD"]:
                    continue
                assert words[0] == "jaxanom", f"{name} block {index}: not a jaxanom command: {words}"
                print("$", shlex.join(words), flush=True)
                assert main(words[1:]) == 0, f"{name} block {index}: {shlex.join(words)} failed"


if __name__ == "__main__":
    run_page(*sys.argv[1:])
