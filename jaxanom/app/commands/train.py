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

    from jaxanom.app.experiment import (Experiment, attention_positions, check_objective, check_schedule,
                                        load_experiment, run_training, with_plugins)
    from jaxanom.train.checkpoint import DamagedCheckpointError
    from jaxanom.train.loop import NonFiniteLossError

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
        with reading("out", out_dir):
            experiment = load_experiment(out_dir)
        if lead:
            claim(out_dir / CLAIM, out_dir)
    else:
        experiment = read_config(config, Experiment, "experiment") if config else _base_experiment(init_from)
    with reading("experiment"):  # the fields' own checks (Experiment, TrainConfig, the objective)
        experiment = _override(experiment, model=model, attention=attention, data=data, data_root=data_root,
                               steps=steps, batch_size=batch_size, seed=seed, distributed=distributed,
                               init_from=init_from, init_modules=init_modules, cudam_position=cudam_position,
                               cudam_gate=cudam_gate, cudam_tau=cudam_tau)
        experiment = with_overrides(experiment, overrides)
        check_objective(experiment)
        check_schedule(experiment)
    _check_recordable(experiment)
    experiment = with_plugins(experiment)
    if lead and not resume:  # claimed once the whole experiment is checked: a refused one leaves no folder
        out_folder(out, overwrite=False, hint="continue the run there with {resume}")
    if experiment.train.objective.name == "cudam":
        positions = attention_positions(experiment, *experiment.crop)
        print(f"CuDAM tau = {experiment.train.objective.reward_weight(positions):.6g} (position "
              f"{experiment.cudam_position}, gate {experiment.cudam_gate})")
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


def _base_experiment(init_from: str | None):
    """The default experiment, with the network of ``init_from``'s run when given."""
    from jaxanom.app.experiment import Experiment, load_experiment

    if init_from is None:
        return Experiment()
    with reading("init_from", init_from):
        source = load_experiment(init_from)
    return Experiment(model=source.model, output_stride=source.output_stride, num_classes=source.num_classes)


def _override(experiment, *, model, attention, data, data_root, steps, batch_size, seed, distributed, init_from,
              init_modules, cudam_position, cudam_gate, cudam_tau):
    """``experiment`` with the arguments given (not None). ``attention`` also sets the objective to
    the module's paper objective unless the config's objective already agrees with it (then its
    settings stay)."""
    from jaxanom.app.experiment import PAPER_OBJECTIVES

    fields = {"model": model, "data": data, "data_root": data_root, "batch_size": batch_size,
              "cudam_position": cudam_position, "cudam_gate": cudam_gate}
    if init_from is not None:
        from jaxanom.app.experiment import load_experiment

        with reading("init_from", init_from):
            load_experiment(init_from)
        fields["init_from"] = str(Path(init_from).resolve())
    if init_modules is not None:
        fields["init_modules"] = tuple(name for name in init_modules.split(",") if name)
    train = {"steps": steps, "seed": seed, "distributed": distributed or None}
    train = {k: v for k, v in train.items() if v is not None}
    objective = experiment.train.objective
    if attention is not None:
        fields["attention"] = None if attention == "none" else attention
        paper = PAPER_OBJECTIVES[fields["attention"]]
        if tuple(objective.needs) != paper.needs:
            objective = paper()
    if cudam_tau is not None:
        if objective.name != "cudam":
            raise InputError("cudam_tau", f": the objective is {objective.name!r}, which has no reward weight "
                             "(pass {attention} cudam)", mentions=("attention",))
        objective = dataclasses.replace(objective, tau=cudam_tau)
    train["objective"] = objective
    fields = {k: v for k, v in fields.items() if v is not None or k == "attention"}
    return dataclasses.replace(experiment, **fields, train=dataclasses.replace(experiment.train, **train))
