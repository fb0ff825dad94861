"""``jaxanom train``: train a network from an ``Experiment`` (a config file, or the defaults) with
fields overridden; ``resume`` continues a run from its last checkpoint."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxanom.app.commands.inputs import load_plugins, read_config, with_overrides
from jaxanom.app.outputs import CLAIM, claim, out_folder
from jaxanom.errors import InputError, reading

__all__ = ["train"]


def train(*, out: str, config: str | None = None, resume: bool = False, model: str | None = None,
          attention: str | None = None, data: str | None = None, data_root: str | None = None,
          steps: int | None = None, batch_size: int | None = None, seed: int | None = None,
          distributed: bool = False, init_from: str | None = None, init_modules: str | None = None,
          cudam_position: str | None = None, cudam_gate: str | None = None, cudam_tau: float | None = None,
          plugins=(), overrides=(), progress: bool = True) -> None:
    """Train into the new or empty run folder ``out`` the experiment of the file ``config`` (a
    Python file defining ``experiment``, or an Experiment's JSON such as a run's experiment.json;
    without it the defaults, or with ``init_from`` that run's network), each argument given (not
    None) replacing its field, then each ``"dotted.name=VALUE"`` of ``overrides``;
    ``attention="none"`` trains without an attention module, and an ``attention`` given also sets
    its paper's objective unless the config's agrees. ``resume`` continues ``out``'s own run.
    ``distributed``: one process per host (``jax.distributed``). ``plugins``: modules imported
    first (e.g. one registering an objective); the run records in its experiment.json those that
    registered the names it uses (``Experiment.plugins``), so every later reading imports them."""
    import jax

    from jaxanom.app.experiment import (Experiment, attention_settings, check_data, check_objective,
                                        check_schedule, load_experiment, output_shapes, run_training, with_plugins)
    from jaxanom.train.checkpoint import DamagedCheckpointError
    from jaxanom.train.segmenter import NonFiniteLossError

    if distributed:  # before any JAX work: loading the data or the model may touch devices
        from jaxanom.train.sharding import initialize_distributed

        with reading("distributed"):
            initialize_distributed()
    load_plugins(plugins)
    lead = jax.process_index() == 0  # on many hosts the first process checks and claims --out for all
    out_dir = Path(out)
    if resume:
        if config or init_from or init_modules:
            raise InputError("resume", " continues the run's own experiment.json; do not pass {config}, {init_from} "
                             "or {init_modules}", mentions=("config", "init_from", "init_modules"))
        if not (out_dir / "experiment.json").is_file():
            raise InputError("out", f"{out_dir}: holds no run to resume (no experiment.json); start one there "
                             "without {resume}", mentions=("resume",))
        with reading("out", out_dir):
            experiment = load_experiment(out_dir)
        if lead:
            claim(out_dir / CLAIM, out_dir)
    else:
        experiment = read_config(config, Experiment, "experiment") if config else _base_experiment(init_from, data)
    with reading("experiment"):  # the fields' own checks (Experiment, TrainConfig, the objective)
        experiment = _override(experiment, model=model, attention=attention, data=data, data_root=data_root,
                               steps=steps, batch_size=batch_size, seed=seed, distributed=distributed,
                               init_from=init_from, init_modules=init_modules, cudam_position=cudam_position,
                               cudam_gate=cudam_gate, cudam_tau=cudam_tau)
        experiment = with_overrides(experiment, overrides)
        if not resume:
            experiment = _initial_weights(experiment)
        check_objective(experiment)
        check_schedule(experiment)
        check_data(experiment)
    _check_recordable(experiment)
    experiment = with_plugins(experiment)
    if lead and not resume:  # claimed once the whole experiment is checked: a refused one leaves no folder
        out_folder(out, overwrite=_unstarted(out_dir, experiment), hint="continue the run there with {resume}")
    line = experiment.train.objective.describe(output_shapes(experiment, *experiment.crop))
    if line:
        position, options = attention_settings(experiment)
        settings = [f"position {position}"] if position else []
        print(f"{line} ({', '.join(settings + [f'{k} {v}' for k, v in options])})" if settings or options else line)
    try:
        run_training(experiment, out_dir, progress=progress)
    except NonFiniteLossError as error:
        raise InputError("overrides", f"the run diverged: {error}. {{resume}} repeats the same steps from there; start "
                         f"a new run with a lower learning rate ({{overrides}} train.optim.lr=..., now "
                         f"{experiment.train.optim.lr:g}) or gradient clipping ({{overrides}} train.optim.clip_norm=...)",
                         mentions=("resume",)) from None
    except DamagedCheckpointError as error:  # only --resume finds checkpoints in --out
        raise InputError("out", f"{out_dir}: {error}") from None
    print(f"trained {experiment.train.steps} steps on {jax.device_count()} devices ({jax.process_count()} "
          f"processes); checkpoints in {out_dir / 'checkpoints'}")


def _check_recordable(experiment) -> None:
    """InputError naming ``config`` when a name the experiment uses was registered by a module that
    a later reading of the run could not import by name (a Python config file, run as a script)."""
    from jaxanom.app.experiment import plugin_modules
    from jaxanom.registry import is_module_name

    for what, module in plugin_modules(experiment).items():
        if not is_module_name(module) or module == "__main__":
            raise InputError("config", f": {what} is registered by {module}, which later readings of the run (resume, "
                             "fit-stats, evaluate, predict) cannot import; register it in a module on the Python path "
                             "and import that module (or name it with {plugins})", mentions=("plugins",))


def _unstarted(out_dir: Path, experiment) -> bool:
    """Whether ``out_dir`` holds nothing but the experiment.json of a start of this very
    ``experiment`` that ended before writing anything else (a crash, ``kill -9``): such a folder is
    started afresh rather than refused. Another experiment's file is refused, naming the field."""
    from jaxanom.app.experiment import changed_fields, check_data, describe_changes, load_experiment

    if not out_dir.is_dir() or {p.name for p in out_dir.iterdir()} - {CLAIM} != {"experiment.json"}:
        return False
    with reading("out", out_dir):
        stored = load_experiment(out_dir)
    differences = changed_fields(stored, experiment)
    if differences:
        try:
            check_data(stored)
            resumable = "{resume} starts that one, or "
        except ValueError:  # e.g. written by a version that checked train.ignore at the first batch only
            resumable = ""
        raise InputError("out", f"{out_dir}: holds the experiment.json of a run that never reached its first "
                         f"checkpoint, of a different experiment ({describe_changes(differences)}); {resumable}"
                         "delete the file, or choose another folder", mentions=("resume",))
    return True


def _initial_weights(experiment):
    """``experiment`` with its ``init_from`` (given by flag, config or ``--set``) checked to be a run
    and stored absolute, so the run records one folder wherever it is resumed from; InputError when
    ``init_modules`` names modules to take from no ``init_from``."""
    from jaxanom.app.experiment import load_experiment

    if experiment.init_from is None:
        if experiment.init_modules is not None:
            raise InputError("init_modules", " takes modules from the run of {init_from}, which is not given",
                             mentions=("init_from",))
        return experiment
    with reading("init_from", experiment.init_from):
        load_experiment(experiment.init_from)
    return dataclasses.replace(experiment, init_from=str(Path(experiment.init_from).resolve()))


def _base_experiment(init_from: str | None, data: str | None):
    """The default experiment, with the network of ``init_from``'s run when given. Its classes are
    ``data``'s (when given), unless the run's network has those or those and a void output (the
    Cityscapes ESPNet and ERFNet): a run fine-tuned on other classes gets a new head."""
    from jaxanom.app.experiment import DATASETS, Experiment, load_experiment

    classes = DATASETS.get(data, Experiment.num_classes)  # an unknown name is refused with the other fields
    if init_from is None:
        return Experiment(num_classes=classes)
    with reading("init_from", init_from):
        source = load_experiment(init_from)
    if data is None or source.num_classes in (classes, classes + 1):
        classes = source.num_classes
    return Experiment(model=source.model, output_stride=source.output_stride, num_classes=classes)


def _override(experiment, *, model, attention, data, data_root, steps, batch_size, seed, distributed, init_from,
              init_modules, cudam_position, cudam_gate, cudam_tau):
    """``experiment`` with the arguments given (not None). ``attention`` also sets the objective to
    the module's paper objective unless the config's objective already agrees with it (then its
    settings stay)."""
    from jaxanom.app.experiment import paper_objective

    fields = {"model": model, "data": data, "data_root": data_root, "batch_size": batch_size,
              "cudam_position": cudam_position, "cudam_gate": cudam_gate}
    if init_from is not None:
        fields["init_from"] = init_from
    if init_modules is not None:
        fields["init_modules"] = tuple(name for name in init_modules.split(",") if name)
    train = {"steps": steps, "seed": seed, "distributed": distributed or None}
    train = {k: v for k, v in train.items() if v is not None}
    objective = experiment.train.objective
    if attention is not None:
        fields["attention"] = None if attention == "none" else attention
        with reading("attention"):
            paper = paper_objective(fields["attention"])
        if tuple(objective.needs) != paper.needs:
            objective = paper()
    if cudam_tau is not None:
        if "tau" not in {field.name for field in dataclasses.fields(objective)}:
            raise InputError("cudam_tau", f": the objective is {objective.name!r}, which has no reward weight tau "
                             "(pass {attention} with a module whose objective has one)", mentions=("attention",))
        objective = dataclasses.replace(objective, tau=cudam_tau)
    train["objective"] = objective
    fields = {k: v for k, v in fields.items() if v is not None or k == "attention"}
    return dataclasses.replace(experiment, **fields, train=dataclasses.replace(experiment.train, **train))
