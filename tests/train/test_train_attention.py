"""The train step with an attention module on each segmenter, trained by its paper's objective:
traced only (no compilation; CuDAM on ERFNet trains for real in tests/app/test_attention_segmenters.py)."""
import functools

import jax
import numpy as np
import pytest

from jaxanom.app.experiment import paper_objective
from jaxanom.models import build_model
from jaxanom.train import step as step_lib
from jaxanom.train.optim import OptimConfig, make_optimizer
from jaxanom.train.state import TrainState
from tiny_models import make_batch


@pytest.mark.parametrize("name", ["erfnet_tiny", "espnet_p1_q1"])
@pytest.mark.parametrize("attention", ["cudam", "msaam"])
def test_the_train_step_traces_with_every_attention_module_on_erfnet_and_espnet(name, attention):
    model = build_model(name, num_classes=5, attention=attention)  # ESPNet: at least 5 (its ESP modules split C by 5)
    batch = make_batch(0, batch=2, size=16)
    variables = jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), batch["image"][:1])
    variables = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), variables)
    tx, _ = make_optimizer(OptimConfig(lr=0.01), 10)
    objective = paper_objective(attention)()
    state = TrainState.create(variables, tx, jax.random.key(0), objective.init_state(5))
    step = functools.partial(step_lib.train_step, model=model, tx=tx, objective=objective)
    new_state, metrics = jax.eval_shape(step, state, batch)
    assert jax.tree.structure(new_state) == jax.tree.structure(state)
    assert attention in new_state.params and metrics["loss"].shape == ()
