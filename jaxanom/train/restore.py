"""Read a finished (or running) training's variables without touching its folder."""
from __future__ import annotations

from pathlib import Path

import jax
import numpy as np

from jaxanom.train.checkpoint import restore_checkpoint
from jaxanom.train.segmenter import TrainConfig, init_inputs


def trained_variables(config: TrainConfig, model, example: dict, step: int | None = None,
                      *, complete: bool = False) -> dict:
    """``{"params", "batch_stats"}`` of the newest (or ``step``) checkpoint in ``config.run_dir``.

    ``example``: one batch as the run's data gives it (``"image"`` and the model's extra inputs;
    shapes only, nothing is computed). Read-only: a training may be writing the folder. ValueError
    naming the folder when there is no checkpoint, it is damaged, or (``complete``) the run stopped
    before ``config.steps``. Only the model's variables (and the step) are read: no optimizer or
    objective state is built or restored, so a run reads back whatever its optimizer and objective.
    """
    images, extras = init_inputs(model, example)
    variables = jax.eval_shape(lambda x, e: model.init(jax.random.key(0), x, train=False, **e), images, extras)
    # the saved state's fields (``TrainState``): a network without BatchNorm saved an empty batch_stats
    template = {"params": variables["params"], "step": jax.ShapeDtypeStruct((), np.int32)}
    if variables.get("batch_stats"):
        template["batch_stats"] = variables["batch_stats"]
    state = restore_checkpoint(Path(config.run_dir) / "checkpoints", template, step, part=True)
    if complete:
        _check_complete(config.run_dir, int(state["step"]), config.steps)
    return jax.device_get({"params": state["params"], "batch_stats": state.get("batch_stats", {})})


def restore_run(run_dir: str | Path, template, steps: int | None = None, step: int | None = None):
    """The state shaped like ``template`` from ``run_dir/checkpoints`` (newest, or ``step``),
    read-only; with ``steps``, ValueError unless the run reached that many steps."""
    state, _ = restore_checkpoint(Path(run_dir) / "checkpoints", template, step)
    if steps is not None:
        _check_complete(run_dir, int(state.step), steps)
    return state


def _check_complete(run_dir, trained: int, steps: int) -> None:
    if trained < steps:
        raise ValueError(f"run_dir {run_dir}: trained {trained} of {steps} steps; finish the training first")
