"""The training loop: logs, evaluation, NaN stop, checkpoints, resume after a crash and after SIGKILL,
extension to more steps, device-to-host reads on logging steps only, the objective's outputs."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxanom.cudam.objective import CuDAM
from jaxanom.train import segmenter as segmenter_lib
from jaxanom.train.checkpoint import Checkpointer, restore_checkpoint
from jaxanom.train.segmenter import NonFiniteLossError, TrainConfig, train
from jaxanom.train.optim import OptimConfig
from jaxanom.train.restore import trained_variables
from compiles import compiled_during
from host_reads import count_host_reads
from tiny_models import TinySegNet, init_variables, make_batch

TESTS = Path(__file__).resolve().parents[1]  # the tests folder: resume_script.py and tiny_models.py


def config(run_dir, **kwargs):
    defaults = dict(steps=6, save_every=3, eval_every=3, keep=2, progress=False, optim=OptimConfig(lr=0.05))
    return TrainConfig(run_dir=str(run_dir), **{**defaults, **kwargs})


def batches(n, crash_at=None):
    """A plain generator (no get_state): batch i is make_batch(i); raises at ``crash_at``."""
    for i in range(n):
        if i == crash_at:
            raise RuntimeError("simulated crash")
        yield make_batch(i)


def flat_params(state):
    return [np.asarray(leaf) for leaf in jax.tree.leaves(jax.device_get(state.params))]


def steps_on_disk(checkpoint_dir):
    return sorted(int(p.name) for p in Path(checkpoint_dir).iterdir() if p.name.isdigit())


def test_crash_and_resume_of_a_plain_iterable_is_bitwise_equal(tmp_path):
    val = [make_batch(100, batch=3, void_fraction=0.3)]  # 3 images on 4 devices: padded with void
    full = train(config(tmp_path / "full"), TinySegNet(), batches(6), val, variables=init_variables())
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(config(tmp_path / "crash"), TinySegNet(), batches(6, crash_at=4), variables=init_variables())
    assert steps_on_disk(tmp_path / "crash" / "checkpoints") == [3]
    resumed = train(config(tmp_path / "crash"), TinySegNet(), batches(6), variables=init_variables())
    assert int(resumed.step) == 6
    for a, b in zip(flat_params(full), flat_params(resumed)):
        np.testing.assert_array_equal(a, b)

    lines = [json.loads(line) for line in (tmp_path / "full" / "log.jsonl").read_text().splitlines()]
    train_lines = [line for line in lines if "train/loss" in line]
    assert [line["step"] for line in train_lines] == [1, 2, 3, 4, 5, 6]
    assert all({"train/loss", "train/lr", "train/images_per_s", "train/grad_norm"} <= set(line) for line in train_lines)
    val_lines = [line for line in lines if "val/miou" in line]
    assert [line["step"] for line in val_lines] == [3, 6] and all(0 <= l["val/miou"] <= 1 for l in val_lines)
    assert any(name.startswith("events.out.tfevents") for name in os.listdir(tmp_path / "full" / "tensorboard"))
    assert steps_on_disk(tmp_path / "full" / "checkpoints") == [3, 6]  # keep=2


def test_a_resumed_run_restores_without_compiling_its_init(tmp_path):
    """Restoring needs only the state's shapes (``jax.eval_shape``): the initial variables of a run
    with a checkpoint were computed, compiled and thrown away (seconds per network, more for big ones)."""
    full = train(config(tmp_path / "full", steps=4, save_every=2), TinySegNet(), batches(4))
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(config(tmp_path / "crash", steps=4, save_every=2), TinySegNet(), batches(4, crash_at=3))
    resumed = train(config(tmp_path / "crash", steps=4, save_every=2), TinySegNet(), batches(4))
    for a, b in zip(flat_params(full), flat_params(resumed)):
        np.testing.assert_array_equal(a, b)

    again, compiles = compiled_during(  # a finished run: restored, nothing computed
        lambda: train(config(tmp_path / "crash", steps=4, save_every=2), TinySegNet(), batches(4)))
    assert int(again.step) == 4 and compiles == [], compiles
    for a, b in zip(flat_params(full), flat_params(again)):
        np.testing.assert_array_equal(a, b)


def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(tmp_path):
    def poisoned():
        for i in range(6):
            batch = make_batch(i)
            if i == 4:
                batch["image"][0, 0, 0, 0] = np.nan
            yield batch

    with pytest.raises(NonFiniteLossError, match=r"at step 5.*last good checkpoint: step 4"):
        train(config(tmp_path, save_every=2), TinySegNet(), poisoned(), variables=init_variables())
    assert steps_on_disk(tmp_path / "checkpoints")[-1] == 4
    template = jax.device_get(train_state_template())
    state, _ = restore_checkpoint(tmp_path / "checkpoints", template)
    assert int(state.step) == 4
    assert all(np.all(np.isfinite(leaf)) for leaf in flat_params(state))


def train_state_template():
    from jaxanom.train.optim import make_optimizer
    from jaxanom.train.state import TrainState

    tx, _ = make_optimizer(OptimConfig(lr=0.05), 10)
    return jax.device_put(TrainState.create(init_variables(), tx, jax.random.key(0)))


def test_missing_checkpoint_folder_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="checkpoint directory.*no_such_run"):
        restore_checkpoint(tmp_path / "no_such_run", train_state_template())
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="expected at least one saved step"):
        restore_checkpoint(tmp_path / "empty", train_state_template())


def test_corrupt_checkpoint_is_a_clear_error_and_not_silently_restarted(tmp_path):
    state = train_state_template()
    with Checkpointer(tmp_path / "checkpoints", save_every=1) as checkpointer:
        checkpointer.save(1, state, {"index": 1})
    for path in (tmp_path / "checkpoints" / "1").rglob("*"):
        if path.is_file():
            path.write_bytes(b"\x00garbage")
    with pytest.raises(ValueError, match=r"checkpoint directory .*checkpoints: step 1 cannot be read"):
        restore_checkpoint(tmp_path / "checkpoints", state)
    with pytest.raises(ValueError, match="step 1 cannot be read"):
        train(config(tmp_path), TinySegNet(), batches(6), variables=init_variables())


def run_script(run_dir, delay_s, env):
    return subprocess.Popen([sys.executable, str(TESTS / "resume_script.py"), str(run_dir), str(delay_s)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def test_sigkill_and_resume_ends_with_bitwise_equal_parameters(tmp_path):
    """A real SIGKILL of a training process after its first checkpoint; the rerun resumes from it.

    All three runs are the same script in fresh processes (same compiled program, shared
    through JAX's persistent compilation cache). On CPU the result is bitwise equal.
    """
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS.parent), str(TESTS)]),
               JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax_cache"),
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
    full = run_script(tmp_path / "full", 0.0, env)
    output = full.communicate(timeout=300)[0].decode()
    assert full.returncode == 0, output

    victim = run_script(tmp_path / "killed", 0.25, env)
    checkpoints = tmp_path / "killed" / "checkpoints"
    deadline = time.monotonic() + 240
    # killed once it has logged a step past its newest checkpoint: the resumed run logs that step again
    while not (checkpoints.is_dir() and steps_on_disk(checkpoints)
               and max(logged_steps(tmp_path / "killed"), default=0) > steps_on_disk(checkpoints)[-1]):
        assert victim.poll() is None, victim.communicate()[0].decode()
        assert time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.05)
    victim.send_signal(signal.SIGKILL)
    victim.communicate(timeout=60)
    assert victim.returncode == -signal.SIGKILL
    assert not (tmp_path / "killed" / "final.npz").exists()
    killed_at = steps_on_disk(checkpoints)
    assert killed_at[-1] < 12 and max(logged_steps(tmp_path / "killed")) > killed_at[-1]

    resumed = run_script(tmp_path / "killed", 0.0, env)
    output = resumed.communicate(timeout=300)[0].decode()
    assert resumed.returncode == 0, output
    expected, got = np.load(tmp_path / "full" / "final.npz"), np.load(tmp_path / "killed" / "final.npz")
    assert sorted(expected.files) == sorted(got.files)
    for name in expected.files:
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)
    # the resumed run's log is the uninterrupted run's: each step once, the same values (bar time and speed)
    want, have = (log_lines(tmp_path / name) for name in ("full", "killed"))
    assert [line["step"] for line in have] == [line["step"] for line in want] == list(range(1, 13))
    assert [_timeless(line) for line in have] == [_timeless(line) for line in want]


def logged_steps(run_dir):
    return [line["step"] for line in log_lines(run_dir)] if (Path(run_dir) / "log.jsonl").is_file() else []


def log_lines(run_dir):
    return [json.loads(line) for line in (Path(run_dir) / "log.jsonl").read_text().splitlines() if line.endswith("}")]


def _timeless(line):
    return {k: v for k, v in line.items() if k not in ("time", "train/images_per_s")}


@pytest.mark.parametrize("change, message", [
    (lambda b: {"image": b["image"]}, "'image' and 'label'"),
    (lambda b: {**b, "image": b["image"][..., :2]}, r"batch\['image'\]"),
    (lambda b: {**b, "label": b["label"].astype(np.float32)}, r"batch\['label'\]: expected int"),
    (lambda b: {**b, "label": np.where(b["label"] == 0, 7, b["label"])}, r"model has 3 classes\), got \[7\]"),
])
def test_bad_first_batch_is_a_clear_error(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        train(config(tmp_path), TinySegNet(), [change(make_batch(0))], variables=init_variables())


@pytest.fixture
def host_reads(monkeypatch):
    """Counts device-to-host reads of jax Arrays (``host_reads.count_host_reads``), each tagged
    with how many train steps had been dispatched when it happened."""
    dispatched = [0]
    reads = count_host_reads(monkeypatch, lambda: dispatched[0])
    make_steps = segmenter_lib.make_steps

    def counting_make_steps(*args, **kwargs):
        train_step, eval_step = make_steps(*args, **kwargs)

        def step(state, batch):
            dispatched[0] += 1
            return train_step(state, batch)

        return step, eval_step

    monkeypatch.setattr(segmenter_lib, "make_steps", counting_make_steps)
    return reads


def test_metrics_are_read_on_logging_steps_only_and_the_objective_state_restores(tmp_path, host_reads):
    """Nothing is read back from the device between logging steps (every 3rd here; the run saves and
    evaluates at the end only), yet every step is logged; the run's objective state (running SML
    statistics) is restored from its shape alone, as the objective declares it."""
    objective = CuDAM(tau=2.5, attention_k="running_sml")  # settings of this test only: a fresh compile
    cfg = config(tmp_path, objective=objective, log_every=3, save_every=6, eval_every=6)
    state = train(cfg, TinySegNet(head="cudam"), batches(6), variables=init_variables("cudam"))
    assert host_reads and set(host_reads) <= {0, 3, 6}, sorted(set(host_reads))
    lines = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert [line["step"] for line in lines] == [1, 2, 3, 4, 5, 6]
    assert all(np.isfinite(line["train/loss"]) and line["train/images_per_s"] > 0 for line in lines)
    np.testing.assert_allclose([line["train/lr"] for line in lines], [0.05 * (1 - t / 6) ** 0.9 for t in range(6)],
                               rtol=1e-6)

    restored = trained_variables(cfg, TinySegNet(head="cudam"), make_batch(0), complete=True)
    for a, b in zip(jax.tree.leaves(jax.device_get(state.variables)), jax.tree.leaves(restored)):
        np.testing.assert_array_equal(a, b)
    saved, _ = restore_checkpoint(tmp_path / "checkpoints", jax.device_get(state))
    assert saved.objective_state.count.shape == (3,) and float(np.sum(saved.objective_state.count)) > 0


def test_a_network_without_the_objectives_outputs_is_refused_before_compiling(tmp_path):
    with pytest.raises(ValueError, match=r"objective 'cudam' reads the model output\(s\) \['attention'\], which "
                                         r"TinySegNet does not produce"):
        compiled_during(lambda: train(config(tmp_path, objective=CuDAM()), TinySegNet(), batches(6)))
    assert not (tmp_path / "checkpoints").exists()


def test_a_finished_run_is_extended_bitwise_and_never_shortened(tmp_path):
    """With a learning rate that does not depend on the step count (poly_power 0), 4 steps then 6
    are the 6-step run; asking a 6-step run for 5 is refused, its checkpoints untouched."""
    flat = OptimConfig(lr=0.05, poly_power=0.0)
    full = train(config(tmp_path / "full", optim=flat, save_every=2), TinySegNet(), batches(6),
                 variables=init_variables())
    train(config(tmp_path / "run", optim=flat, steps=4, save_every=2), TinySegNet(), batches(6),
          variables=init_variables())
    extended = train(config(tmp_path / "run", optim=flat, save_every=2), TinySegNet(), batches(6),
                     variables=init_variables())
    assert int(extended.step) == 6 and steps_on_disk(tmp_path / "run" / "checkpoints") == [4, 6]
    for a, b in zip(flat_params(full), flat_params(extended)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match=r"steps: expected at least the 6 steps the run in .*run has trained, got 5"):
        train(config(tmp_path / "run", optim=flat, steps=5, save_every=2), TinySegNet(), batches(6))
    assert steps_on_disk(tmp_path / "run" / "checkpoints") == [4, 6]


def test_validation_metrics_equal_numpy_from_the_networks_argmax():
    from jaxanom.train.step import model_input

    model, variables, run = TinySegNet(), init_variables(), config("")  # the steps the other tests compiled
    mesh, *_, eval_step = segmenter_lib._compiled(model, run.objective, run.optim, run.steps, run.compute_dtype,
                                                  run.ignore, tuple(jax.devices()))
    val = [make_batch(50 + i, void_fraction=0.3) for i in range(3)]
    with jax.set_mesh(mesh):
        got = segmenter_lib.evaluate(eval_step, variables, val, mesh, 255, model)
        with pytest.raises(ValueError, match="val_data: expected at least one batch"):
            segmenter_lib.evaluate(eval_step, variables, [], mesh, 255, model)
    prediction = np.concatenate([np.argmax(model.apply(variables, model_input(b["image"], model))["logits"], -1)
                                 for b in val]).ravel()
    label = np.concatenate([b["label"] for b in val]).ravel()
    prediction, label = prediction[label != 255], label[label != 255]
    iou = [np.sum((prediction == k) & (label == k)) / np.sum((prediction == k) | (label == k)) for k in range(3)]
    assert got["val/miou"] == pytest.approx(np.mean(iou), rel=1e-12)
    assert got["val/pixel_accuracy"] == pytest.approx(np.mean(prediction == label), rel=1e-12)
