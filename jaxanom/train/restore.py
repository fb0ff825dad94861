"""Read a finished (or running) training's variables without touching its folder."""
from __future__ import annotations

from pathlib import Path

import jax

from jaxanom.train.checkpoint import restore_checkpoint
from jaxanom.train.loop import TrainConfig, init_inputs, output_classes
from jaxanom.train.optim import make_optimizer
from jaxanom.train.state import TrainState


def trained_variables(config: TrainConfig, model, example: dict, step: int | None = None,
                      *, complete: bool = False) -> dict:
    """``{"params", "batch_stats"}`` of the newest (or ``step``) checkpoint in ``config.run_dir``.

    ``example``: one batch as the run's data gives it (``"image"`` and the model's extra inputs;
    shapes only, nothing is computed). Read-only: a training may be writing the folder. ValueError
    naming the folder when there is no checkpoint, it is damaged, or (``complete``) the run stopped
    before ``config.steps``.
    """
    images, extras = init_inputs(model, example)
    tx, _ = make_optimizer(config.optim, config.steps)
    objective_state = config.objective.init_state(output_classes(model, example))
    template = jax.eval_shape(
        lambda x, e: TrainState.create(model.init(jax.random.key(0), x, train=False, **e), tx, jax.random.key(0),
                                       objective_state), images, extras)
    state = restore_run(config.run_dir, template, config.steps if complete else None, step)
    return jax.device_get(state.variables)


def restore_run(run_dir: str | Path, template, steps: int | None = None, step: int | None = None):
    """The state shaped like ``template`` from ``run_dir/checkpoints`` (newest, or ``step``),
    read-only; with ``steps``, ValueError unless the run reached that many steps."""
    state, _ = restore_checkpoint(Path(run_dir) / "checkpoints", template, step)
    if steps is not None and int(state.step) < steps:
        raise ValueError(f"run_dir {run_dir}: trained {int(state.step)} of {steps} steps; finish the training first")
    return state
