"""``python -m experiments``'s command line: bad flags refused before any work, and a smoke run
never overwrites the results of a full run."""
import json

import pytest

import experiments.__main__ as runner
from experiments.common import HERE


@pytest.mark.parametrize("flags, flag", [(["--size", "0", "0"], "--size"), (["--size", "60", "128"], "--size"),
                                         (["--steps", "0"], "--steps"), (["--train-frames", "-1"], "--train-frames"),
                                         (["--anomaly", "bogus"], "--anomaly"),
                                         (["--anomaly", "smiyc:/no/such/track"], "--anomaly"),
                                         (["--cityscapes", "/no/such/root"], "--cityscapes")])
def test_a_bad_flag_is_refused_in_one_line_naming_it(flags, flag, capsys):
    with pytest.raises(SystemExit) as exit_:
        runner.parse_args(flags)
    errors = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
    assert exit_.value.code == 2 and len(errors) == 1 and f"error: {flag}" in errors[0]


def test_a_smoke_run_writes_elsewhere_and_refuses_a_folder_of_full_results(tmp_path, capsys):
    assert runner.parse_args([]).out == HERE and runner.parse_args(["--smoke"]).out == runner.SMOKE_OUT != HERE
    with pytest.raises(SystemExit):  # the committed results
        runner.parse_args(["--smoke", "--out", str(HERE)])
    assert "holds the results of a full run" in capsys.readouterr().err
    full = tmp_path / "full"
    full.mkdir()
    (full / "cudam_table2.json").write_text("{}")  # results without a record of how they were made: a full run's
    with pytest.raises(SystemExit):
        runner.parse_args(["--smoke", "--out", str(full)])
    assert runner.parse_args(["--out", str(full)]).out == full  # a full run may rewrite them
    (full / runner.MADE_BY).write_text(json.dumps({"smoke": True}))
    assert runner.parse_args(["--smoke", "--out", str(full)]).out == full  # a smoke run's own results
    (full / runner.MADE_BY).write_text(json.dumps({"smoke": False}))
    with pytest.raises(SystemExit):
        runner.parse_args(["--smoke", "--out", str(full)])


def test_the_runner_records_how_its_results_were_made(tmp_path, monkeypatch):
    import jax

    tables = []
    monkeypatch.setattr(runner, "jobs_of", lambda *args: [])
    monkeypatch.setattr(runner, "run_table", lambda name, *args, **kwargs: tables.append(name))
    cache = jax.config.jax_compilation_cache_dir
    try:
        out = tmp_path / "smoke"
        assert runner.main(["--smoke", "--only", "cudam_table2", "--out", str(out), "--runs", str(tmp_path)]) == 0
        assert tables == ["cudam_table2"] and json.loads((out / runner.MADE_BY).read_text())["smoke"] is True
        assert (out / "RESULTS.md").read_text().startswith("> **A smoke run**")
        assert runner.main(["--only", "cudam_table2", "--out", str(out), "--runs", str(tmp_path)]) == 0
        assert json.loads((out / runner.MADE_BY).read_text())["smoke"] is False  # now a full run's: kept from smoke
        assert not (out / "RESULTS.md").read_text().startswith("> **A smoke run**")
    finally:
        jax.config.update("jax_compilation_cache_dir", cache)
    with pytest.raises(SystemExit):
        runner.parse_args(["--smoke", "--out", str(out)])
