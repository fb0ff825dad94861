"""``jaxanom train``: train a network from a config file or flags; ``--resume`` continues."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxanom.cli.common import (CLAIM, CommandError, add_common, add_config, claim, nonnegative_int, out_folder,
                                positive_int, read_config, with_set)


def add_parser(commands) -> None:
    parser = commands.add_parser("train", help="train a network (config file or flags); --resume continues",
                                 description="Train a DeepLabV3+ (optionally with CuDAM or MSAAM). A config file is "
                                 "a Python file that defines `experiment`, a jaxanom.app.experiment.Experiment, or its "
                                 "JSON (a run's experiment.json); flags, then --set, override its fields.")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, logs, experiment.json); "
                        "must be new or empty unless --resume")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    parser.add_argument("--model", help="model preset, e.g. deeplabv3plus_tiny, deeplabv3plus_r101")
    parser.add_argument("--attention", choices=["none", "cudam", "msaam"], help="attention module")
    parser.add_argument("--data", choices=["synthetic", "cityscapes"], help="training data")
    parser.add_argument("--data-root", help="dataset folder (Cityscapes layout)")
    parser.add_argument("--steps", type=positive_int, help="training steps")
    parser.add_argument("--batch-size", type=positive_int, help="global batch size")
    parser.add_argument("--seed", type=nonnegative_int, help="random seed")
    parser.add_argument("--distributed", action="store_true",
                        help="multi-host: one process per host, joined by jax.distributed.initialize (SLURM, Open MPI "
                        "and TPU pods are detected; see the README)")
    parser.add_argument("--init-from", help="start from the weights of this run folder (e.g. from convert-weights); "
                        "without --config or --model the network's preset, output stride and classes are its")
    parser.add_argument("--init-modules", help="comma-separated top-level modules to take from --init-from, "
                        "e.g. backbone (default: all it has)")
    parser.add_argument("--cudam-position", choices=["deep", "surface", "output"],
                        help="CuDAM's place: deep (paper's best), surface (pre-classifier variant), "
                        "output (the paper's surface: on the logits)")
    parser.add_argument("--cudam-gate", choices=["paper", "scale_free"],
                        help="Eq. 3 as printed, or with h*w*M_att (a deviation; see jaxanom.nn.cudam)")
    parser.add_argument("--cudam-tau", type=float,
                        help="CuDAM reward weight (Eq. 4); default: the CuDAM objective's, the paper's 5e4 rescaled to "
                        "this network's attention-map size at the crop size (equivalent_weight), unless a config file "
                        "set another tau; the value used is printed")
    add_config(parser, "Python file defining `experiment = Experiment(...)`, or an Experiment's JSON "
               "(e.g. a run's experiment.json)")
    add_common(parser, progress=True, overwrite=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    import jax

    from jaxanom.app.experiment import Experiment, attention_positions, check_objective, load_experiment, run_training

    if args.distributed:  # before any JAX work: loading the data or the model may touch devices
        from jaxanom.train.sharding import initialize_distributed

        initialize_distributed()
    lead = jax.process_index() == 0  # on many hosts the first process checks and claims --out for all
    out = Path(args.out)
    if args.resume:
        if args.config or args.init_from or args.init_modules:
            raise CommandError("--resume continues the run's own experiment.json; do not pass --config or --init-*")
        experiment = load_experiment(out)
        if lead:
            claim(out / CLAIM, f"--out {out}")
    else:
        experiment = read_config(args.config, Experiment, "experiment") if args.config else \
            _base_experiment(args.init_from)
        if lead:
            out_folder(args.out, overwrite=False, hint="continue the run there with --resume")
    experiment = with_set(_override(experiment, args), args)
    check_objective(experiment)
    if experiment.train.objective.name == "cudam":
        positions = attention_positions(experiment, *experiment.crop)
        print(f"CuDAM tau = {experiment.train.objective.reward_weight(positions):.6g} (position "
              f"{experiment.cudam_position}, gate {experiment.cudam_gate})")
    from jaxanom.train.loop import NonFiniteLossError

    try:
        run_training(experiment, out, progress=not args.no_progress)
    except NonFiniteLossError as error:
        raise CommandError(f"the run diverged: {error}. --resume repeats the same steps from there; start a new run "
                           f"with a lower learning rate (--set train.optim.lr=..., now {experiment.train.optim.lr:g}) "
                           "or gradient clipping (--set train.optim.clip_norm=...)") from None
    print(f"trained {experiment.train.steps} steps on {jax.device_count()} devices ({jax.process_count()} "
          f"processes); checkpoints in {out / 'checkpoints'}")


def _base_experiment(init_from: str | None):
    """The default experiment, with the network of ``init_from``'s run when given."""
    from jaxanom.app.experiment import Experiment, load_experiment

    if init_from is None:
        return Experiment()
    source = load_experiment(init_from)  # ValueError unless it is a run folder
    return Experiment(model=source.model, output_stride=source.output_stride, num_classes=source.num_classes)


def _override(experiment, args):
    """``experiment`` with the flags given. ``--attention`` also sets the objective to the module's
    paper objective unless the config's objective already agrees with it (then its settings stay)."""
    from jaxanom.app.experiment import PAPER_OBJECTIVES

    fields = {"model": args.model, "data": args.data, "data_root": args.data_root, "batch_size": args.batch_size,
              "cudam_position": args.cudam_position, "cudam_gate": args.cudam_gate}
    if args.init_from is not None:
        from jaxanom.app.experiment import load_experiment

        load_experiment(args.init_from)  # ValueError unless it is a run folder
        fields["init_from"] = str(Path(args.init_from).resolve())
    if args.init_modules is not None:
        fields["init_modules"] = tuple(name for name in args.init_modules.split(",") if name)
    train = {"steps": args.steps, "seed": args.seed, "distributed": args.distributed or None}
    train = {k: v for k, v in train.items() if v is not None}
    objective = experiment.train.objective
    if args.attention is not None:
        fields["attention"] = None if args.attention == "none" else args.attention
        paper = PAPER_OBJECTIVES[fields["attention"]]
        if tuple(objective.needs) != paper.needs:
            objective = paper()
    if args.cudam_tau is not None:
        if objective.name != "cudam":
            raise CommandError(f"--cudam-tau: the objective is {objective.name!r}, which has no reward weight "
                               "(pass --attention cudam)")
        objective = dataclasses.replace(objective, tau=args.cudam_tau)
    train["objective"] = objective
    fields = {k: v for k, v in fields.items() if v is not None or k == "attention"}
    return dataclasses.replace(experiment, **fields, train=dataclasses.replace(experiment.train, **train))
