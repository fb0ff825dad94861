"""Integration: the real (tiny) DeepLabV3+ from jaxanom.models through the train step (CuDAM run, all heads traced)."""
import functools

import jax
import numpy as np
import pytest

from jaxanom.app.experiment import paper_objective
from jaxanom.cudam.objective import CuDAM
from jaxanom.models import build_model
from jaxanom.train import step as step_lib
from jaxanom.train.optim import OptimConfig, make_optimizer
from jaxanom.train.sharding import global_batch, make_mesh, replicated
from jaxanom.train.state import TrainState
from tiny_models import make_batch, numpy_variables


def test_tiny_deeplab_with_cudam_trains():
    model = build_model("deeplabv3plus_tiny", num_classes=3, attention="cudam", output_stride=16)
    mesh = make_mesh()
    tx, _ = make_optimizer(OptimConfig(lr=0.01), 10)
    variables = numpy_variables(model, 32)
    state = jax.device_put(TrainState.create(variables, tx, jax.random.key(0)), replicated(mesh))
    train, _ = step_lib.make_steps(model, tx, CuDAM(), mesh)
    for seed in range(2):
        state, metrics = train(state, global_batch(make_batch(seed, batch=4, size=32), mesh))
        assert all(np.isfinite(float(value)) for value in metrics.values())
    assert int(state.step) == 2
    before, after = variables["params"], jax.device_get(state.params)
    assert not np.array_equal(before["classifier"]["kernel"], after["classifier"]["kernel"])
    # alpha = 0 at first cuts the attention conv off from the features: only the reward (Eq. 4)
    # and the attention loss (Eq. 7) move it
    assert not np.array_equal(before["cudam"]["attention_conv"]["kernel"], after["cudam"]["attention_conv"]["kernel"])


@pytest.mark.parametrize("attention", [None, "msaam"])
def test_tiny_deeplab_train_step_traces_for_every_attention(attention):
    """The step's contract with the other model heads, checked by tracing only (no compilation)."""
    model = build_model("deeplabv3plus_tiny", num_classes=3, attention=attention, output_stride=16)
    tx, _ = make_optimizer(OptimConfig(lr=0.01), 10)
    state = TrainState.create(numpy_variables(model, 32), tx, jax.random.key(0))
    step = functools.partial(step_lib.train_step, model=model, tx=tx, objective=paper_objective(attention)())
    new_state, metrics = jax.eval_shape(step, state, make_batch(0, batch=2, size=32))
    assert jax.tree.structure(new_state) == jax.tree.structure(state)
    assert all(a.shape == b.shape and a.dtype == b.dtype
               for a, b in zip(jax.tree.leaves(new_state), jax.tree.leaves(state)))
    assert metrics["loss"].shape == () and metrics["loss"].dtype == np.float32
