"""The shared step loop: metrics read on logging steps only, the checkpoint policies, resume, the
NaN stop, evaluation steps and the progress wrapper, on a one-line step (no network)."""
import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from host_reads import count_host_reads
from jaxanom.train.run_loop import Checkpoints, NonFiniteLossError, run_loop


@flax.struct.dataclass
class State:
    w: jax.Array
    step: jax.Array


def fresh() -> State:
    return State(w=jnp.zeros(3), step=jnp.zeros((), jnp.int32))


@jax.jit
def step(state: State, batch) -> tuple[State, dict]:
    w = 0.5 * state.w + batch
    return State(w=w, step=state.step + 1), {"loss": jnp.sum(w), "peak": jnp.max(w)}


def batch(index: int) -> np.ndarray:
    return np.array([index, 1.0, -index], np.float32)


def expected(steps: int) -> np.ndarray:
    """The state after ``steps`` steps, in NumPy."""
    w = np.zeros(3, np.float32)
    for index in range(steps):
        w = np.float32(0.5) * w + batch(index)
    return w


class Batches:
    """Batch i is ``batch(i)``; ``fail_at`` raises there (a crash); ``resumable`` adds get_state / set_state."""

    def __init__(self, fail_at: int | None = None, resumable: bool = False):
        self.index, self.fail_at, self.reads = 0, fail_at, 0
        if resumable:
            self.get_state = lambda: {"index": self.index}
            self.set_state = lambda state: setattr(self, "index", state["index"])

    def __iter__(self):
        return self

    def __next__(self):
        if self.index == self.fail_at:
            raise RuntimeError("simulated crash")
        self.index, self.reads = self.index + 1, self.reads + 1
        return batch(self.index - 1)


def saved_steps(run_dir) -> list[int]:
    folder = run_dir / "checkpoints"
    return sorted(int(p.name) for p in folder.iterdir() if p.name.isdigit()) if folder.exists() else []


def run(steps, batches, **kwargs):
    logged = []
    state = run_loop(step, fresh, batches, steps, on_log=lambda rows, _: logged.extend(rows), **kwargs)
    return state, logged


def counted(monkeypatch):
    """A step that counts its calls, and the host reads, each tagged with the steps dispatched before it."""
    dispatched = [0]

    def counting_step(state, batch):
        dispatched[0] += 1
        return step(state, batch)

    return counting_step, count_host_reads(monkeypatch, lambda: dispatched[0])


def test_metrics_are_read_on_logging_steps_only_and_every_step_is_logged(monkeypatch):
    counting_step, reads = counted(monkeypatch)
    logged = []
    state = run_loop(counting_step, fresh, Batches(), 7, log_every=3, on_log=lambda rows, _: logged.extend(rows))
    assert reads and set(reads) <= {3, 6, 7}, sorted(set(reads))  # every 3rd step and the last
    assert [number for number, _ in logged] == list(range(1, 8))
    w = np.zeros(3, np.float32)
    for number, metrics in logged:  # each step's own metrics, in order
        w = np.float32(0.5) * w + batch(number - 1)
        assert metrics["loss"] == np.sum(w) and metrics["peak"] == np.max(w)
    np.testing.assert_array_equal(jax.device_get(state.w), expected(7))


def test_without_a_logging_interval_or_checkpoints_the_metrics_are_read_once_at_the_end(monkeypatch):
    counting_step, reads = counted(monkeypatch)
    logged = []
    state = run_loop(counting_step, fresh, Batches(), 4, on_log=lambda rows, _: logged.extend(rows))
    assert reads and set(reads) == {4}, sorted(set(reads))
    assert int(state.step) == 4 and [number for number, _ in logged] == [1, 2, 3, 4]


@pytest.mark.parametrize("every, saved", [(2, [4, 5]), (None, [5])])
def test_checkpoints_every_n_steps_or_at_the_end_keeping_the_newest(tmp_path, every, saved):
    state, logged = run(5, Batches(), checkpoints=Checkpoints(str(tmp_path), every, keep=2))
    assert saved_steps(tmp_path) == saved  # every 2: steps 2, 4 and the last, 5; the newest two kept
    assert [number for number, _ in logged] == [1, 2, 3, 4, 5]
    again = Batches()
    finished = run_loop(step, fresh, again, 5, checkpoints=Checkpoints(str(tmp_path), every))
    assert again.reads == 0 and int(finished.step) == 5  # a finished run is restored and reads no batch
    np.testing.assert_array_equal(jax.device_get(finished.w), expected(5))


@pytest.mark.parametrize("resumable", [False, True])
def test_a_crashed_run_resumes_from_its_newest_checkpoint_bitwise(tmp_path, resumable):
    policy = Checkpoints(str(tmp_path), every=2)
    with pytest.raises(RuntimeError, match="simulated crash"):
        run(6, Batches(fail_at=3, resumable=resumable), checkpoints=policy)
    assert saved_steps(tmp_path) == [2]
    batches = Batches(resumable=resumable)
    state, logged = run(6, batches, checkpoints=policy)
    assert [number for number, _ in logged] == [3, 4, 5, 6]
    np.testing.assert_array_equal(jax.device_get(state.w), expected(6))
    # the position comes from the checkpoint (set_state) or from skipping the 2 batches used
    assert batches.reads == (4 if resumable else 6)
    with pytest.raises(ValueError, match=r"steps: expected at least the 6 steps the run in .* has trained, got 5"):
        run(5, Batches(), checkpoints=policy)
    assert saved_steps(tmp_path) == [2, 4, 6]


def test_a_first_batch_taken_by_the_caller_is_stepped_on_first_and_not_skipped_twice(tmp_path):
    policy = Checkpoints(str(tmp_path), every=2)
    source = Batches()
    state, _ = run(2, source, first=next(source), checkpoints=policy)
    np.testing.assert_array_equal(jax.device_get(state.w), expected(2))
    source = Batches()
    state, _ = run(4, source, first=next(source), checkpoints=policy)  # resumed at 2: batch 0 taken, 1 skipped
    np.testing.assert_array_equal(jax.device_get(state.w), expected(4))


def test_a_non_finite_metric_stops_before_saving_it(tmp_path):
    def poisoned():
        for index in range(6):
            yield np.full(3, np.nan, np.float32) if index == 4 else batch(index)

    with pytest.raises(NonFiniteLossError, match=r"loss nan, peak nan at step 5: training stopped; last good "
                                                 r"checkpoint: step 4 in .*checkpoints"):
        run(6, poisoned(), checkpoints=Checkpoints(str(tmp_path), every=2), log_every=3)
    assert saved_steps(tmp_path) == [2, 4]
    with pytest.raises(NonFiniteLossError, match="peak nan at step 5: training stopped; nothing was saved"):
        run(6, poisoned(), finite=("peak",))
    state, logged = run(6, poisoned(), finite=())  # nothing watched: the run goes on
    assert np.isnan(logged[4][1]["loss"]) and int(state.step) == 6


def test_evaluation_steps_and_the_progress_wrapper():
    evaluated, bars, summaries = [], [], []

    class Bar:
        def __init__(self, numbers):
            self.numbers, self.closed = numbers, False
            bars.append(self)

        def __iter__(self):
            return iter(self.numbers)

        def set_postfix(self, summary):
            summaries.append(summary)

        def close(self):
            self.closed = True

    run_loop(step, fresh, Batches(), 7, log_every=5, eval_every=3, examples=len, progress=Bar,
             evaluate=lambda number, state: evaluated.append((number, int(state.step))),
             on_log=lambda rows, per_s: {"last": rows[-1][0], "per_s": per_s})
    assert evaluated == [(3, 3), (6, 6), (7, 7)]  # every 3 steps and the last, on the state of that step
    assert [bar.numbers for bar in bars] == [range(1, 8)] and bars[0].closed
    assert [summary["last"] for summary in summaries] == [3, 5, 6, 7]  # logging steps: evaluations, every 5, the last
    assert all(summary["per_s"] > 0 for summary in summaries)


def test_non_finite_weights_under_finite_metrics_stop_the_run_before_they_are_saved(tmp_path):
    """A step whose metrics stay finite while the state does not (a NaN clip norm scales the update,
    not the loss): the state is checked before each save and at the last step, and a run that
    saved nothing says so (not "step None")."""
    @jax.jit
    def poisoning(state, batch):
        new, metrics = step(state, batch)
        return new.replace(w=jnp.where(new.step >= 3, jnp.nan, new.w)), {"loss": jnp.sum(batch)}

    def go(steps, **kwargs):
        return run_loop(poisoning, fresh, Batches(), steps, **kwargs)

    with pytest.raises(NonFiniteLossError, match=r"hold NaN or Inf after step 4: training stopped; last good "
                                                 r"checkpoint: step 2 in .*checkpoints"):
        go(6, checkpoints=Checkpoints(str(tmp_path), every=2))
    assert saved_steps(tmp_path) == [2]
    with pytest.raises(NonFiniteLossError, match=r"after step 3: training stopped; no checkpoint was saved before"):
        go(3, checkpoints=Checkpoints(str(tmp_path / "none")))
    assert saved_steps(tmp_path / "none") == []
    with pytest.raises(NonFiniteLossError, match="after step 3: training stopped; nothing was saved"):
        go(3)
    assert np.isnan(jax.device_get(go(3, finite=()).w)).all()  # nothing watched: the caller judges


def test_a_run_that_saved_nothing_says_so_when_its_loss_turns_non_finite(tmp_path):
    def poisoned():
        for index in range(3):
            yield np.full(3, np.nan, np.float32) if index == 1 else batch(index)

    with pytest.raises(NonFiniteLossError, match=r"at step 2: training stopped; no checkpoint was saved before"):
        run(3, poisoned(), checkpoints=Checkpoints(str(tmp_path)))
