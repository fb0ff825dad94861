"""``jaxanom predict --threads``: parsed into the command's ``threads`` (None without), checked as >= 1."""
import pytest

from jaxanom.cli import main


def test_threads_flag_reaches_the_command(monkeypatch, capsys):
    calls = []
    monkeypatch.setattr("jaxanom.app.commands.predict.predict", lambda *args, **kwargs: calls.append(kwargs))
    common = ["predict", "x.png", "--run", "r", "--out", "o"]
    assert main([*common, "--threads", "3"]) == 0 and main(common) == 0
    assert [call["threads"] for call in calls] == [3, None]
    with pytest.raises(SystemExit) as exit_:
        main([*common, "--threads", "0"])
    assert exit_.value.code == 2 and "--threads" in capsys.readouterr().err
