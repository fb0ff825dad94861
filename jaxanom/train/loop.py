"""The training driver: config, state set-up or resume, the step loop, logging, evaluation, checkpoints.

``train(config, model, train_data, val_data)`` runs ``config.steps`` train steps. ``train_data``
is any iterable of batches ``{"image": (B, H, W, 3) uint8 RGB or float32 normalised, "label":
(B, H, W) int32}`` (this process's share of the global batch). When its iterator has
``get_state`` / ``set_state`` (grain's ``DatasetIterator`` has them), the position is saved
with each checkpoint as JSON and restored on resume; otherwise a resumed run skips as many
batches as were already used, which is right for any deterministic input. On multi-host runs
the saved position is process 0's, right when every process's pipeline advances alike (grain
with one shard per process). A run folder that already holds checkpoints is resumed from the
newest one; a damaged newest checkpoint stops the run with a ValueError (nothing is silently
restarted).

On CPU a run that is killed and resumed ends with parameters bitwise equal to an uninterrupted
run (tests/test_train_loop.py); on GPUs this holds as far as their kernels are deterministic.

The steps' metrics stay on the device until a logging step (every ``log_every`` steps, and every
step that evaluates or saves, and the last): reading them back every step would make the host
wait for each step before it dispatches the next. They are then read at once, checked for
NaN/Inf (before anything is saved) and written, one line per step.
"""
from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import os
import time
from typing import Any, Iterable

import jax
import numpy as np

from jaxanom._validate import check_count
from jaxanom.metrics.segmentation import confusion_scores
from jaxanom.train.checkpoint import Checkpointer
from jaxanom.train.optim import OptimConfig, make_optimizer
from jaxanom.train.runlog import RunLog
from jaxanom.train.sharding import global_batch, initialize_distributed, make_mesh, replicated
from jaxanom.losses import IGNORE, CrossEntropy
from jaxanom.objectives import Objective
from jaxanom.train.state import TrainState
from jaxanom.train.step import COMPUTE_DTYPES, check_outputs, make_steps, model_extras, model_input


class NonFiniteLossError(FloatingPointError):
    """The loss or the gradient became NaN or infinite; the run stopped before saving it."""


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
    """mIoU and pixel accuracy of ``variables`` over ``batches`` (summed confusion matrix)."""
    total = None
    for batch in batches:
        batch = global_batch(pad_batch(step_inputs(batch, model), len(mesh.local_devices), ignore), mesh)
        confusion = eval_step(variables, batch)
        total = confusion if total is None else total + confusion
    if total is None:
        raise ValueError("val_data: expected at least one batch, got none")
    scores = confusion_scores(np.asarray(jax.device_get(total)))
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


def _data_state(batches) -> Any:
    state = batches.get_state()
    return state.decode() if isinstance(state, bytes) else state


def _set_data_state(batches, state: Any) -> None:
    batches.set_state(state.encode() if isinstance(state, str) else state)


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
    resumable = hasattr(source, "get_state") and hasattr(source, "set_state")
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

    make_state = jax.jit(new_state, out_shardings=replicated(mesh))
    checkpointer = Checkpointer(os.path.join(config.run_dir, "checkpoints"), config.save_every, config.keep)
    pending = [first]
    if checkpointer.latest_step() is None:
        state = make_state(variables)
    else:  # restored into the state's shapes and shardings alone: a resumed or finished run compiles no init
        state, data_state = checkpointer.restore(jax.eval_shape(make_state, variables))
        pending = []
        if int(state.step) > config.steps:
            checkpointer.close()
            raise ValueError(f"steps: expected at least the {int(state.step)} steps the run in {config.run_dir} "
                             f"has trained, got {config.steps}")
        if resumable and data_state is not None:
            _set_data_state(source, data_state)
        else:
            for _ in range(int(state.step) - 1):
                next(source)
    batches = itertools.chain(pending, source)

    is_main = jax.process_index() == 0
    log = RunLog(config.run_dir, enabled=is_main)
    start = int(state.step)
    from tqdm.auto import tqdm

    bar = tqdm(total=config.steps, initial=start, disable=not (config.progress and is_main), dynamic_ncols=True)
    unread = []  # (step, images, metrics still on the device) since the last logging step
    tick = time.perf_counter()
    try:
        for step in range(start + 1, config.steps + 1):
            batch = global_batch(step_inputs(next(batches), model), mesh)
            state, metrics = train_step(state, batch)
            unread.append((step, batch["image"].shape[0], metrics))
            bar.update(1)
            evaluates = val_data is not None and (step % config.eval_every == 0 or step == config.steps)
            saves = step == config.steps or checkpointer.is_due(step)
            if not (evaluates or saves or step % config.log_every == 0):
                continue
            _log_metrics(unread, lr_at, time.perf_counter() - tick, log, bar, checkpointer)
            unread = []
            if evaluates:
                log.scalars(step, evaluate(eval_step, state.variables, val_data, mesh, config.ignore, model))
            if saves:
                checkpointer.save(step, state, _data_state(source) if resumable else None)
            tick = time.perf_counter()
        checkpointer.wait()
    finally:
        bar.close()
        log.close()
        checkpointer.close()
    return state


def _log_metrics(unread: list, lr_at, seconds: float, log: RunLog, bar, checkpointer: Checkpointer) -> None:
    """Read the metrics of the ``unread`` steps from the device in one go, stop at the first
    non-finite loss or gradient (NonFiniteLossError, nothing saved), log one line per step.
    ``images_per_s`` is the mean over these steps (the device runs ahead of the host)."""
    steps = np.array([step for step, _, _ in unread])
    values, lrs = jax.device_get(([metrics for _, _, metrics in unread], lr_at(steps - 1)))
    images_per_s = sum(images for _, images, _ in unread) / seconds
    for step, lr, metrics in zip(steps.tolist(), lrs.tolist(), values):
        metrics = {name: float(value) for name, value in metrics.items()}
        if not (math.isfinite(metrics["loss"]) and math.isfinite(metrics["grad_norm"])):
            checkpointer.wait()
            raise NonFiniteLossError(
                f"loss {metrics['loss']}, gradient norm {metrics['grad_norm']} at step {step}: training "
                f"stopped; last good checkpoint: step {checkpointer.latest_step()} in {checkpointer.directory}")
        metrics.update(lr=lr, images_per_s=images_per_s)
        log.scalars(step, {f"train/{name}": value for name, value in metrics.items()})
    bar.set_postfix(loss=f"{metrics['loss']:.4f}", lr=f"{metrics['lr']:.2e}", img_s=f"{images_per_s:.1f}")
