"""The segmenter's trainer: config, state set-up, the train and eval steps on ``train.run_loop``.

``train(config, model, train_data, val_data)`` runs ``config.steps`` train steps. ``train_data``
is any iterable of batches ``{"image": (B, H, W, 3) uint8 RGB or float32 normalised, "label":
(B, H, W) int32}`` (this process's share of the global batch). Resume, checkpoints (every
``save_every`` steps and at the end, in ``run_dir/checkpoints``), the input position saved with
them and the metric reads on logging steps are ``jaxanom.train.run_loop``'s: a run folder that
already holds checkpoints is resumed from the newest one; a damaged newest checkpoint stops the
run with a ValueError (nothing is silently restarted).

On CPU a run that is killed and resumed ends with parameters bitwise equal to an uninterrupted
run (tests/train/test_train_segmenter.py); on GPUs this holds as far as their kernels are deterministic.

The metrics are read from the device on logging steps only (every ``log_every`` steps, every step
that evaluates or saves, and the last), checked for NaN/Inf (before anything is saved) and
written, one line per step.
"""
from __future__ import annotations

import dataclasses
import functools
import os
from typing import Any, Iterable

import jax
import numpy as np

from jaxanom._validate import check_count
from jaxanom.metrics.evaluator import ConfusionSum, run_evaluators
from jaxanom.train.optim import OptimConfig, make_optimizer
from jaxanom.train.run_loop import NonFiniteLossError  # noqa: F401  (part of this module's API: train raises it)
from jaxanom.train.run_loop import Checkpoints, progress_bar, run_loop
from jaxanom.train.runlog import RunLog
from jaxanom.train.sharding import global_batch, initialize_distributed, make_mesh, replicated
from jaxanom.losses import IGNORE, CrossEntropy
from jaxanom.objectives import Objective
from jaxanom.train.state import TrainState
from jaxanom.train.step import COMPUTE_DTYPES, check_outputs, make_steps, model_extras, model_input


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """A training run. ``objective``: what the steps minimise (``jaxanom.objectives``; default
    cross-entropy); ``optim`` defaults to the segmentation papers' settings (SGD, lr 0.01, momentum
    0.9, weight decay 5e-4, poly 0.9). The papers do not state the number of steps; 40k is a
    common DeepLabV3+ Cityscapes schedule.

    ``compute_dtype``: of the forward pass (``"float32"`` or ``"bfloat16"``; master weights and
    losses stay float32). ``ignore``: the label of void pixels. ``eval_every`` / ``save_every`` /
    ``log_every``: every that many steps and at the end (metrics are read from the device on
    logging steps only). ``keep``: newest checkpoints kept. ``distributed``: call
    ``jax.distributed.initialize`` (multi-host runs).
    """

    run_dir: str
    steps: int = 40_000
    seed: int = 0
    objective: Objective = dataclasses.field(default_factory=CrossEntropy)
    optim: OptimConfig = dataclasses.field(default_factory=OptimConfig)
    compute_dtype: str = "float32"
    ignore: int = IGNORE
    eval_every: int = 2000
    save_every: int = 1000
    log_every: int = 50
    keep: int = 3
    progress: bool = True
    distributed: bool = False

    def __post_init__(self):
        for name in ("steps", "eval_every", "save_every", "log_every", "keep"):
            check_count(name, getattr(self, name))
        check_count("seed", self.seed, minimum=0, maximum=2**63 - 1)
        check_count("ignore", self.ignore, minimum=0)
        if not isinstance(self.objective, Objective):
            raise ValueError(f"objective: expected a jaxanom.objectives.Objective, got {type(self.objective).__name__}")
        if self.compute_dtype not in COMPUTE_DTYPES:
            raise ValueError(f"compute_dtype: expected one of {tuple(COMPUTE_DTYPES)}, got {self.compute_dtype!r}")


def pad_batch(batch: dict, multiple: int, ignore: int) -> dict:
    """Pad a batch's leading axis to a multiple of ``multiple``: zero images, all-void labels."""
    size = len(batch["label"])
    extra = -size % multiple
    if not extra:
        return batch
    fill = {"label": ignore}
    return {name: np.concatenate([value, np.full((extra,) + value.shape[1:], fill.get(name, 0), value.dtype)])
            for name, value in ((n, np.asarray(v)) for n, v in batch.items())}


def step_inputs(batch: dict, model=None) -> dict:
    """The arrays a step reads (with ``model``'s ``extra_inputs``); other entries of a pipeline's
    batch (names, depth) stay on the host."""
    return {"image": batch["image"], "label": batch["label"], **model_extras(model, batch)}


def evaluate(eval_step, variables, batches: Iterable[dict], mesh, ignore: int, model=None) -> dict[str, float]:
    """mIoU and pixel accuracy of ``variables`` over ``batches``: the eval step's confusion
    matrices, summed on the device and read once (``metrics.evaluator.ConfusionSum``)."""
    confusions = ({"confusion": eval_step(variables, global_batch(
        pad_batch(step_inputs(batch, model), len(mesh.local_devices), ignore), mesh))} for batch in batches)
    try:
        scores = run_evaluators({"val": ConfusionSum()}, confusions)["val"]
    except ValueError as error:
        if str(error).startswith("batches:"):  # no batch at all
            raise ValueError("val_data: expected at least one batch, got none") from None
        raise
    return {"val/miou": scores["miou"], "val/pixel_accuracy": scores["pixel_accuracy"]}


def check_batch(batch: Any, num_classes: int, ignore: int) -> None:
    """ValueError unless ``batch`` is ``{"image": (B, H, W, 3) uint8 or float, "label": (B, H, W) int}``
    with labels in [0, num_classes) or ``ignore``. The loop checks the first batch only."""
    if not isinstance(batch, dict) or not {"image", "label"} <= set(batch):
        got = sorted(batch) if isinstance(batch, dict) else type(batch).__name__
        raise ValueError(f"train_data: expected batches as dicts with 'image' and 'label', got {got}")
    image, label = np.asarray(batch["image"]), np.asarray(batch["label"])
    if image.ndim != 4 or image.shape[-1] != 3 or not (image.dtype == np.uint8 or np.issubdtype(image.dtype, np.floating)):
        raise ValueError(f"batch['image']: expected uint8 or float (B, H, W, 3), got {image.dtype} {image.shape}")
    if label.shape != image.shape[:3] or not np.issubdtype(label.dtype, np.integer):
        raise ValueError(f"batch['label']: expected int {image.shape[:3]}, got {label.dtype} {label.shape}")
    bad = (label != ignore) & ((label < 0) | (label >= num_classes))
    if bad.any():
        raise ValueError(f"batch['label']: expected values in [0, {num_classes}) or {ignore} (the model has "
                         f"{num_classes} classes), got {np.unique(label[bad])[:10].tolist()}")


def init_inputs(model, batch: dict) -> tuple[jax.Array, dict]:
    """The first example of ``batch`` as ``model.init`` wants it: (images, extra keyword inputs)."""
    return model_input(np.asarray(batch["image"][:1]), model), {k: np.asarray(v[:1]) for k, v in model_extras(model, batch).items()}


def model_outputs(model, batch: dict) -> dict:
    """The shapes (``jax.ShapeDtypeStruct``) of ``model``'s outputs for one example of ``batch``; no compute."""
    images, extras = init_inputs(model, batch)
    return jax.eval_shape(lambda x, e: model.init_with_output(jax.random.key(0), x, train=False, **e)[0], images, extras)


def output_classes(model, batch: dict) -> int:
    return model_outputs(model, batch)["logits"].shape[-1]


def train(config: TrainConfig, model, train_data: Iterable[dict], val_data: Iterable[dict] | None = None,
          variables: dict | None = None) -> TrainState:
    """Train ``model`` (the jaxanom.models contract) and return the final state.

    ``val_data`` must be re-iterable (a list, a grain dataset); it is evaluated every
    ``config.eval_every`` steps. ``variables`` (``{"params", "batch_stats"}``, e.g. with a
    pretrained backbone) replace ``model.init`` for a fresh run; a resumed run ignores them.
    Raises NonFiniteLossError when the loss or gradient stops being finite, leaving the last
    good checkpoint in ``run_dir/checkpoints``.
    """
    if config.distributed:
        initialize_distributed()
    compiled = _compiled(model, config.objective, config.optim, config.steps, config.compute_dtype, config.ignore,
                         tuple(jax.devices()))
    with jax.set_mesh(compiled[0]):
        return _run(config, model, train_data, val_data, variables, *compiled)


@functools.lru_cache(maxsize=4)
def _compiled(model, objective: Objective, optim: OptimConfig, steps: int, compute_dtype: str, ignore: int,
              devices: tuple):
    """Mesh, optimizer, schedule and jitted steps; a later run with equal settings reuses them."""
    mesh = make_mesh(devices)
    tx, lr_at = make_optimizer(optim, steps)
    return (mesh, tx, lr_at) + make_steps(model, tx, objective, mesh, compute_dtype=compute_dtype, ignore=ignore)


def _run(config: TrainConfig, model, train_data, val_data, variables, mesh, tx, lr_at, train_step, eval_step) -> TrainState:
    os.makedirs(config.run_dir, exist_ok=True)
    source = iter(train_data)
    first = next(source)
    outputs = model_outputs(model, first)
    check_outputs(config.objective, outputs, model)
    num_classes = outputs["logits"].shape[-1]
    check_batch(first, num_classes, config.ignore)

    init_key, state_key = jax.random.split(jax.random.key(config.seed))

    def new_state(variables):
        if variables is None:
            images, extras = init_inputs(model, first)
            variables = model.init(init_key, images, train=False, **extras)
        return TrainState.create(variables, tx, state_key, config.objective.init_state(num_classes))

    is_main = jax.process_index() == 0
    log = RunLog(config.run_dir, enabled=is_main)

    def log_steps(logged: list, images_per_s: float) -> dict:
        """One line per step; ``images_per_s`` is the mean over these steps (the device runs ahead of the host)."""
        lrs = jax.device_get(lr_at(np.array([step for step, _ in logged]) - 1))
        for (step, metrics), lr in zip(logged, lrs.tolist()):
            metrics = {name: float(value) for name, value in metrics.items()}
            metrics.update(lr=lr, images_per_s=images_per_s)
            log.scalars(step, {f"train/{name}": value for name, value in metrics.items()})
        return {"loss": f"{metrics['loss']:.4f}", "lr": f"{metrics['lr']:.2e}", "img_s": f"{images_per_s:.1f}"}

    def validate(step: int, state: TrainState) -> None:
        log.scalars(step, evaluate(eval_step, state.variables, val_data, mesh, config.ignore, model))

    try:  # the state is made on the mesh: a resumed or finished run restores into its shardings, compiling no init
        return run_loop(lambda state, batch: train_step(state, global_batch(step_inputs(batch, model), mesh)),
                        jax.jit(new_state, out_shardings=replicated(mesh)), source, config.steps,
                        init_args=(variables,), first=first,
                        checkpoints=Checkpoints(config.run_dir, config.save_every, config.keep),
                        log_every=config.log_every, on_log=log_steps, finite=("loss", "grad_norm"),
                        examples=lambda batch: len(batch["label"]) * jax.process_count(),
                        evaluate=None if val_data is None else validate, eval_every=config.eval_every,
                        progress=progress_bar(config.progress and is_main))
    finally:
        log.close()
