"""Every example that a command's --help shows (a whole flag usage in backticks) is run, on tiny
inputs, up to the command's work: an example the command refuses is a defect of its help."""
import re
import shlex

import cv2
import numpy as np
import pytest

from converted_run import tiny_run, write_tiny_cityscapes  # noqa: F401  (tiny_run: the module fixture, a tiny converted run)
from jaxanom.cli import _parser, main


class Reached(Exception):
    """Raised in place of a command's work: every check before it passed."""


def _reached(*args, **kwargs):
    raise Reached


def examples() -> dict[str, list[str]]:
    """``{command: [example, ...]}``: the backticked texts starting with ``--`` in each command's
    description, epilog and flag help."""
    commands = next(a for a in _parser()._actions if a.dest == "command").choices
    found = {}
    for name, parser in commands.items():
        texts = [parser.description or "", parser.epilog or ""] + [a.help or "" for a in parser._actions]
        found[name] = [span for text in texts for span in re.findall(r"`([^`]*)`", text) if span.startswith("--")]
    return found


EXAMPLES = examples()
# each command with examples: its arguments on tiny inputs, and the function doing its work
BASES = {
    "demo": (lambda tmp, run: ["demo", "--quick", "--out", str(tmp / "o"), "--no-progress"],
             "jaxanom.app.demos.sml_cudam.run_demo"),
    "train": (lambda tmp, run: ["train", "--out", str(tmp / "o"), "--init-from", str(run), "--no-progress"],
              "jaxanom.app.experiment.run_training"),
    "fit-stats": (lambda tmp, run: ["fit-stats", "--run", str(run), "--frames", "1", "--out", str(tmp / "s.npz"),
                                    "--cityscapes", str(write_tiny_cityscapes(tmp / "cs", [(64, 128)]))],
                  "jaxanom.app.evaluate.class_statistics"),
    "predict": (lambda tmp, run: ["predict", _image(tmp), "--run", str(run), "--out", str(tmp / "o"),
                                  "--methods", "msp", "--no-progress"], "jaxanom.app.predict.predict_images"),
}


def _image(tmp):
    cv2.imwrite(str(tmp / "a.png"), np.zeros((6, 10, 3), np.uint8))
    return str(tmp / "a.png")


def test_the_examples_are_found_and_each_command_showing_some_has_a_base():
    assert {name for name, found in EXAMPLES.items() if found} == set(BASES)
    assert "--set experiment.train.optim.lr=1e-3" in EXAMPLES["demo"] and len(EXAMPLES["train"]) == 4


@pytest.mark.parametrize("command, example", [(c, e) for c, found in EXAMPLES.items() for e in found])
def test_every_help_example_runs(command, example, tiny_run, tmp_path, monkeypatch, capsys):  # noqa: F811
    base, work = BASES[command]
    monkeypatch.setattr(work, _reached)
    with pytest.raises(Reached):
        main([*base(tmp_path, tiny_run), *shlex.split(example)])
    assert capsys.readouterr().err == ""
