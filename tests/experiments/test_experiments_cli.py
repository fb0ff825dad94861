"""``python -m experiments``'s command line: bad flags refused before any work, and smoke and full
runs never share a folder (a smoke run never overwrites a full run's results, a full run never
mixes its tables with a smoke run's)."""
import json

import pytest

import experiments.__main__ as runner
from experiments.common import HERE


@pytest.mark.parametrize("flags, flag", [(["--size", "0", "0"], "--size"), (["--size", "60", "128"], "--size"),
                                         (["--steps", "0"], "--steps"), (["--steps", "1"], "--steps"),
                                         (["--train-frames", "-1"], "--train-frames"),
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
    with pytest.raises(SystemExit):  # a full run would mix its tables with a smoke run's
        runner.parse_args(["--only", "sml_table3_table7", "--out", str(full)])
    assert "holds the results of a smoke run" in capsys.readouterr().err
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
        with pytest.raises(SystemExit):  # refused before any work: the smoke label and banner stay true
            runner.main(["--only", "msaam_table6", "--out", str(out), "--runs", str(tmp_path)])
        assert tables == ["cudam_table2"] and json.loads((out / runner.MADE_BY).read_text())["smoke"] is True
        assert (out / "RESULTS.md").read_text().startswith("> **A smoke run**")
        full = tmp_path / "full"
        assert runner.main(["--only", "cudam_table2", "--out", str(full), "--runs", str(tmp_path)]) == 0
        assert json.loads((full / runner.MADE_BY).read_text())["smoke"] is False
        assert not (full / "RESULTS.md").read_text().startswith("> **A smoke run**")
    finally:
        jax.config.update("jax_compilation_cache_dir", cache)
    assert runner.parse_args(["--smoke", "--out", str(out)]).out == out  # a later smoke run may go on there
    with pytest.raises(SystemExit):
        runner.parse_args(["--smoke", "--out", str(full)])
