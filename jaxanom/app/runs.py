"""Run folders of converted weights: ``write_run(folder, preset, model, variables)`` makes a DeepLabV3+,
ESPNet or ERFNet run folder (``experiment.json`` and one checkpoint, step 0 for converted weights),
which ``jaxanom evaluate --run``, ``predict --run`` and ``train --init-from`` read like any trained run.
"""
from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np

from jaxanom.io import write_json_atomic


def write_run(folder: str | os.PathLike, preset: str, model, variables: dict, step: int = 0, **fields):
    """Write ``variables`` of ``model`` (built by ``build_model(preset, ...)``) as a run of one
    checkpoint at ``step``: 0 for converted weights (a network with no training frames of its own).

    The experiment keeps jaxanom's defaults for everything but the network (model preset,
    classes, attention module; for a DeepLabV3+ also the output stride) and ``fields`` (other
    ``Experiment`` fields): a network trained outside ``jaxanom train`` passes the steps it was
    trained and e.g. ``data="camvid", data_root=...``, whose training frames ``fit-stats`` then
    reads. Returns the ``Experiment``.
    """
    from jaxanom.app.experiment import Experiment, jsonable
    from jaxanom.models import DeepLabV3Plus
    from jaxanom.models.attention import get
    from jaxanom.train.checkpoint import Checkpointer, check_space
    from jaxanom.train.optim import make_optimizer
    from jaxanom.train.state import TrainState

    network = {"attention": model.attention}
    if model.attention is not None:  # the module's position and options, in the fields that record them
        recorded_as = get(model.attention).recorded_as
        settings = {"position": model.attention_position, **dict(model.attention_options)}
        settings = {key: value for key, value in settings.items() if value is not None}
        unrecorded = sorted(set(settings) - set(recorded_as))
        if unrecorded:
            raise ValueError(f"model: the settings {unrecorded} of its attention module have no field in a run")
        network.update({recorded_as[key]: value for key, value in settings.items()})
    if isinstance(model, DeepLabV3Plus):
        network["output_stride"] = model.output_stride
    experiment = Experiment(model=preset, num_classes=model.num_classes, **network, **fields)
    folder = Path(folder)
    write_json_atomic(folder / "experiment.json", jsonable(experiment), allow_nan=False)
    tx, _ = make_optimizer(experiment.train.optim, experiment.train.steps)
    state = TrainState.create(jax.tree.map(np.asarray, variables), tx, jax.random.key(0))
    state = state.replace(step=np.int32(step))
    check_space(folder, state, "the converted run")  # before orbax starts any background writer
    with Checkpointer(folder / "checkpoints") as checkpointer:
        checkpointer.save(step, state)
        checkpointer.wait()
    return experiment
