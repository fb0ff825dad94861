"""Every configuration checked before the first step; one-line errors instead of tracebacks."""
import json
import math
import time

import numpy as np
import pytest

from jaxanom.cli import main
from jaxanom.app.configs import encode, load_config
from jaxanom.app.offroad_experiment import OffroadDemoConfig


class Custom:
    """An object that only unpickling (running code) can rebuild."""


def _one_line(capsys, code, *fragments):
    error = capsys.readouterr().err.strip()
    assert code == 2 and len(error.splitlines()) == 1 and "Traceback" not in error, error
    for fragment in fragments:
        assert fragment in error, error
    return error


def _refused_at_once(capsys, argv, *fragments, out=None):
    """The command fails in one line within seconds (no training first), leaving no output folder."""
    tick = time.perf_counter()
    error = _one_line(capsys, main(argv), *fragments)
    assert time.perf_counter() - tick < 20, f"refused only after {time.perf_counter() - tick:.0f} s: {error}"
    assert out is None or not out.exists() or not list(out.iterdir())
    return error


@pytest.mark.parametrize("config, fragments", [
    ({"pipeline": {"rgbd_channels": -8}}, ["rgbd_channels must be >= 1"]),
    ({"pipeline": {"rgbd_channels": 0}}, ["rgbd_channels must be >= 1"]),
    ({"pipeline": {"rgbd_steps": 2.5}}, ["pipeline.rgbd_steps: expected an integer, got 2.5"]),
    ({"pipeline": {"dissim_lr": "abc"}}, ["pipeline.dissim_lr: expected a number, got 'abc'"]),
    ({"pipeline": {"dissim_lr": math.nan}}, ["pipeline.dissim_lr: expected a finite number, got nan"]),
    ({"pipeline": {"slic_step": 0}}, ["slic_step must be >= 1"]),
    ({"pipeline": {"dissim_width": 0}}, ["dissim_width"]),
    ({"pipeline": {"dissim_width": -0.5}}, ["dissim_width"]),
    ({"pipeline": {"batch_size": 1e9}}, ["pipeline.batch_size: expected an integer, got 1000000000.0"]),
    ({"pipeline": {"batch_size": 10**9}}, ["batch_size", "GiB of memory"]),
    ({"anomaly_frames": 0}, ["anomaly_frames must be >= 1"]),
    ({"anomaly_split": "bogus"}, ["anomaly_split: expected one of"]),
    ({"pictures": -1}, ["pictures must be >= 0"]),
])
def test_demo_mmf_config_is_checked_before_any_training(tmp_path, capsys, config, fragments):
    file = tmp_path / "mmf.json"
    file.write_text(json.dumps(config))
    out = tmp_path / "out"
    _refused_at_once(capsys, ["demo", "mmf", "--config", str(file), "--out", str(out), "--no-progress"],
                     "--config", *fragments, out=out)


def test_a_segmenter_with_a_nan_learning_rate_is_refused(tmp_path, capsys):
    from jaxanom.app.experiment import jsonable
    from jaxanom.app.mmf_pipeline import MMFConfig

    segmenter = jsonable(MMFConfig.quick().segmenter)
    segmenter["train"]["optim"]["lr"] = math.nan
    file = tmp_path / "mmf.json"
    file.write_text(json.dumps({"pipeline": {"segmenter": segmenter}}))
    _refused_at_once(capsys, ["demo", "mmf", "--config", str(file), "--out", str(tmp_path / "o")],
                     "train.optim.lr: expected a finite number, got nan")


@pytest.mark.parametrize("config, fragment", [
    ({"pipeline": {"encoder": {"dim": 0}}}, "dim must be >= 1"),
    ({"pipeline": {"encoder": {"size": 0}}}, "size must be >= 1"),
    ({"pipeline": {"risk": "bogus"}}, "risk: expected one of ('calibrated', 'literal')"),
    ({"pipeline": {"selection": "bogus"}}, "selection: expected one of ('dp', 'greedy')"),
    ({"pipeline": {"delta": 2}}, "delta must be a finite number in (0.0, 1.0]"),
    ({"pipeline": {"stride": 0}}, "stride must be >= 1"),
    ({"pipeline": {"budget": 0}}, "budget must be >= 1"),
    ({"pipeline": {"budget": 30, "gap": 3}}, "need 117 frames, the active source has 60"),
    ({"segmented": -1}, "segmented must be >= 1"),
    ({"test": {"domain": "Z", "frames": 3}}, "domain: expected one of"),
])
def test_demo_offroad_config_is_checked_before_any_stage(tmp_path, capsys, config, fragment):
    file = tmp_path / "offroad.json"
    file.write_text(json.dumps(config))
    out = tmp_path / "out"
    _refused_at_once(capsys, ["demo", "offroad", "--config", str(file), "--out", str(out), "--no-progress"],
                     fragment, out=out)


def test_demo_offroad_reads_its_own_results_json_as_config(tmp_path):
    quick = OffroadDemoConfig.quick()
    # what run_offroad_demo writes in results.json
    results = {"test_after": {}, "config": encode(quick)}
    (tmp_path / "results.json").write_text(json.dumps(results))
    assert load_config(tmp_path / "results.json", OffroadDemoConfig) == quick


def test_train_batch_size_beyond_memory_is_refused_before_allocating(tmp_path, capsys):
    _refused_at_once(capsys, ["train", "--batch-size", str(10**9), "--out", str(tmp_path / "run"), "--no-progress"],
                     "batch_size", "GiB of memory", out=tmp_path / "run")


@pytest.mark.parametrize("argv", [["evaluate", "--run", "r", "--dataset", "synthetic", "--path", "anomaly",
                                   "--out", "o", "--pictures", "-2"],
                                  ["train", "--out", "o", "--steps", "0"], ["demo", "--steps", "-1"]])
def test_negative_counts_are_refused_by_the_parser(capsys, argv):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2 and "expected an integer" in capsys.readouterr().err


def test_evaluate_mmf_on_a_dataset_without_disparity_is_one_line(tmp_path, capsys, road_anomaly_sample):
    (tmp_path / "mmf").mkdir()
    (tmp_path / "mmf" / "results.json").write_text(json.dumps({"config": {}}))
    _refused_at_once(capsys, ["evaluate", "--mmf", str(tmp_path / "mmf"), "--dataset", "road-anomaly", "--path",
                              str(road_anomaly_sample), "--out", str(tmp_path / "o")],
                     "road-anomaly dataset has no disparity", out=tmp_path / "o")


def test_distributed_without_a_cluster_is_one_line(tmp_path, capsys, monkeypatch):
    for name in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr("jax.distributed.is_initialized", lambda: False)
    for name in [n for n in __import__("os").environ if n.startswith(("SLURM_", "OMPI_", "TPU_"))]:
        monkeypatch.delenv(name)
    _refused_at_once(capsys, ["train", "--distributed", "--out", str(tmp_path / "r")],
                     "cannot join a multi-host run", "JAX_COORDINATOR_ADDRESS")


def test_distributed_with_an_unreachable_coordinator_times_out_with_a_message(tmp_path, capsys, monkeypatch):
    import socket

    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    monkeypatch.setenv("JAX_COORDINATOR_ADDRESS", f"127.0.0.1:{port}")
    monkeypatch.setenv("JAX_NUM_PROCESSES", "2")
    monkeypatch.setenv("JAX_PROCESS_ID", "1")
    monkeypatch.setenv("JAXANOM_DISTRIBUTED_TIMEOUT", "1")
    _refused_at_once(capsys, ["train", "--distributed", "--out", str(tmp_path / "r")],
                     f"coordinator 127.0.0.1:{port} did not answer within 1 s")


def test_convert_weights_input_problems_are_one_line_and_never_advise_unsafe_loading(tmp_path, capsys):
    torch = pytest.importorskip("torch")
    sparse = torch.zeros(4, 3, 7, 7)
    torch.save({"conv1.weight": sparse.to_sparse()}, tmp_path / "sparse.pth")
    _one_line(capsys, main(["convert-weights", "--from", "torchvision-resnet18", str(tmp_path / "sparse.pth"),
                            str(tmp_path / "a")]), "conv1.weight", "sparse_coo tensor", "to_dense")
    torch.save({"conv1.weight": torch.zeros(2), "extra": Custom()}, tmp_path / "objects.pth")
    error = _one_line(capsys, main(["convert-weights", "--from", "torchvision-resnet18",
                                    str(tmp_path / "objects.pth"), str(tmp_path / "b")]),
                      "refused", "Custom", "save the state dict alone")
    assert "weights_only=False" not in error and "\x1b" not in error and error.endswith("safetensors")
    (tmp_path / "damaged.pth").write_bytes(b"\x80\x02not a checkpoint" * 7)
    error = _one_line(capsys, main(["convert-weights", "--from", "torchvision-resnet18", str(tmp_path / "damaged.pth"),
                                    str(tmp_path / "c")]), "not a readable PyTorch checkpoint", "Unsupported operand")
    assert "weights_only" not in error and "\x1b" not in error
    assert not any((tmp_path / name).exists() for name in "abc")


def test_convert_weights_unwraps_a_model_checkpoint_and_names_integer_tensors():
    from jaxanom.weights import state_dict_arrays
    from jaxanom.weights.mapping import fill_variables

    state = state_dict_arrays({"model": {"conv.weight": np.ones((2, 1, 1, 1), np.int64),
                                         "conv.bias": np.full(2, np.nan, np.float32)}, "optimizer": {"lr": 0.1}})
    assert sorted(state) == ["conv.bias", "conv.weight"]
    template = {"params": {"conv": {"kernel": np.zeros((1, 1, 1, 2)), "bias": np.zeros(2)}}}
    with pytest.raises(ValueError, match=r"not finite floating-point tensors \(2\): conv.bias \(2 NaN/Inf\); "
                       r"conv.weight \(int64, expected floats\)"):
        fill_variables(state, template, lambda path: "conv", lambda key: False, "a net")


def test_a_junk_synthesizer_file_is_named_without_pickle_advice(tmp_path):
    from jaxanom.app.mmf_pipeline import MMFConfig, _run_dir, load_synthesizer

    config = MMFConfig.quick()
    junk = _run_dir(config, tmp_path, "synthesizer").with_suffix(".npz")
    np.savez(junk, means=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ValueError, match="not class means written by jaxanom .it holds Python objects.") as error:
        load_synthesizer(config, tmp_path)
    assert "allow_pickle" not in str(error.value)
    np.savez(junk, means=np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match=r"shape \(20, 3\)"):
        load_synthesizer(config, tmp_path)


def test_stats_in_an_npy_file_name_the_flag(tmp_path, capsys):
    np.save(tmp_path / "stats.npy", np.zeros(3, np.float32))
    np.save(tmp_path / "logits.npy", np.zeros((1, 3, 4, 5), np.float32))
    _one_line(capsys, main(["score", "--logits", str(tmp_path / "logits.npy"), "--stats", str(tmp_path / "stats.npy"),
                            "--methods", "sml", "--out", str(tmp_path / "o")]), "--stats", "an .npy file")


@pytest.mark.parametrize("out, fragment", [("folder/", "names a folder"), ("stats.txt", "ending in .npz")])
def test_fit_stats_out_must_name_an_npz_file(tmp_path, capsys, out, fragment):
    _one_line(capsys, main(["fit-stats", "--run", str(tmp_path), "--out", str(tmp_path / "x") + "/" + out]), fragment)
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("methods, fragment", [("bogus", "methods: expected names from"),
                                               ("sml", "need SML class statistics")])
def test_evaluate_checks_its_methods_before_reading_the_network(tmp_path, capsys, methods, fragment):
    from jaxanom.app.experiment import Experiment, jsonable

    (tmp_path / "run").mkdir()  # a run without checkpoints: reading its network would fail
    (tmp_path / "run" / "experiment.json").write_text(json.dumps(jsonable(Experiment())))
    _refused_at_once(capsys, ["evaluate", "--run", str(tmp_path / "run"), "--dataset", "synthetic", "--path", "anomaly",
                              "--methods", methods, "--out", str(tmp_path / "o")], fragment, out=tmp_path / "o")


@pytest.mark.parametrize("variables, fragments", [
    ({"JAX_NUM_PROCESSES": "two", "JAX_PROCESS_ID": "0"}, ["JAX_NUM_PROCESSES", "integer >= 1", "'two'"]),
    ({"JAX_NUM_PROCESSES": "0", "JAX_PROCESS_ID": "0"}, ["JAX_NUM_PROCESSES", "integer >= 1", "'0'"]),
    ({"JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": "-1"}, ["JAX_PROCESS_ID", "integer >= 0", "'-1'"]),
    ({"JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": "2"}, ["JAX_PROCESS_ID", "below JAX_NUM_PROCESSES=2", "got 2"]),
])
def test_distributed_environment_variables_are_checked_in_one_line(tmp_path, capsys, monkeypatch, variables,
                                                                   fragments):
    monkeypatch.setattr("jax.distributed.is_initialized", lambda: False)
    monkeypatch.setenv("JAX_COORDINATOR_ADDRESS", "127.0.0.1:1")
    for name, value in variables.items():
        monkeypatch.setenv(name, value)
    _refused_at_once(capsys, ["train", "--distributed", "--out", str(tmp_path / "r")], *fragments,
                     out=tmp_path / "r")
