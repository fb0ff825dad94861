"""jaxanom.train.restore: a run's model variables read without its optimizer or objective state."""
import jax
import numpy as np
import optax
import pytest

from jaxanom.cudam.objective import CuDAM
from jaxanom.train.checkpoint import Checkpointer, DamagedCheckpointError
from jaxanom.train.segmenter import TrainConfig
from jaxanom.train.restore import trained_variables
from jaxanom.train.state import TrainState
from tiny_models import TinySegNet, init_variables, make_batch


def saved_run(folder, variables, step=5, objective_state=None, nan_in_optimizer=False):
    """A run's checkpoint as training writes it: the whole TrainState (AdamW state, step, key, objective state)."""
    state = TrainState.create(variables, optax.adamw(1e-3), jax.random.key(1), objective_state)
    state = state.replace(step=np.int32(step))
    if nan_in_optimizer:
        state = state.replace(opt_state=jax.tree.map(lambda x: np.full(np.shape(x), np.nan, np.float32)
                                                     if np.issubdtype(np.asarray(x).dtype, np.floating) else x,
                                                     state.opt_state))
    with Checkpointer(folder / "checkpoints") as checkpointer:
        checkpointer.save(step, state)
        checkpointer.wait()


def test_inference_reads_the_variables_without_building_the_optimizer_or_the_objective_state(tmp_path, monkeypatch):
    """The run's checkpoint holds CuDAM's running statistics and AdamW's moments; the reader builds
    neither (both are made to fail here) and gets the variables bitwise."""
    variables = init_variables("cudam")
    objective = CuDAM(attention_k="running_sml")
    saved_run(tmp_path, variables, objective_state=objective.init_state(3))

    def refuse(*args, **kwargs):
        raise AssertionError("inference built training state")

    monkeypatch.setattr(TrainState, "create", refuse)
    monkeypatch.setattr(CuDAM, "init_state", refuse)
    config = TrainConfig(run_dir=str(tmp_path), steps=5, objective=objective)
    restored = trained_variables(config, TinySegNet(head="cudam"), make_batch(0), complete=True)
    assert jax.tree.structure(restored) == jax.tree.structure(variables)
    jax.tree.map(np.testing.assert_array_equal, restored, variables)


def test_what_inference_does_not_read_does_not_stop_it_and_the_step_count_is_still_checked(tmp_path):
    variables = init_variables()
    saved_run(tmp_path, variables, step=4, nan_in_optimizer=True)  # the optimizer's state is no input to inference
    config = TrainConfig(run_dir=str(tmp_path), steps=5)
    jax.tree.map(np.testing.assert_array_equal, trained_variables(config, TinySegNet(), make_batch(0)), variables)
    with pytest.raises(ValueError, match="trained 4 of 5 steps; finish the training first"):
        trained_variables(config, TinySegNet(), make_batch(0), complete=True)


def test_damaged_variables_are_still_named(tmp_path):
    variables = init_variables()
    broken = jax.tree.map(np.copy, variables)
    first = jax.tree_util.tree_leaves_with_path(broken["params"])[0][1]
    first.reshape(-1)[0] = np.nan
    saved_run(tmp_path, broken)
    with pytest.raises(DamagedCheckpointError, match=r"step 5 holds NaN/Inf in 1 array\(s\), e.g. \['params'\]"):
        trained_variables(TrainConfig(run_dir=str(tmp_path), steps=5), TinySegNet(), make_batch(0))
