"""``jaxanom demo``: train, fit SML statistics and evaluate on synthetic scenes."""
from __future__ import annotations

import dataclasses

from jaxanom.cli.common import add_common, out_folder, positive_int


def add_parser(commands) -> None:
    parser = commands.add_parser("demo", help="train, fit SML statistics and evaluate on synthetic scenes",
                                 description="Train a small DeepLabV3+ with CuDAM on synthetic driving scenes, fit "
                                 "SML statistics, evaluate MSP / max logit / entropy / energy / SML / SML + "
                                 "post-processing / CuDAM on a synthetic anomaly split; write a table, "
                                 "results.json and pictures.")
    parser.add_argument("paper", nargs="?", choices=["mmf", "offroad"],
                        help="another paper's demo instead: mmf (multi-mechanism fusion, jaxanom.mmf.demo) or "
                        "offroad (active + contrastive off-road segmentation, jaxanom.offroad.demo)")
    parser.add_argument("--out", default="jaxanom-demo", help="output folder (default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run of the same path at tiny sizes (minutes on a CPU, mostly compiling)")
    parser.add_argument("--steps", type=positive_int, help="training steps (default: 1500; --quick: 3)")
    parser.add_argument("--config", help="offroad: a JSON file of OffroadDemoConfig fields; mmf: a JSON file of "
                        "MMFDemoConfig fields, e.g. the \"config\" of a results.json (every trainable part)")
    parser.add_argument("--synthesizer", choices=["class_mean", "spade"],
                        help="mmf: the resynthesis (default: class_mean)")
    add_common(parser, progress=True)
    parser.set_defaults(handler=run)


def run(args) -> None:
    if args.paper == "offroad":
        from jaxanom.offroad.demo import run_from_args

        return run_from_args(args)
    if args.paper == "mmf":
        from jaxanom.mmf.demo import run_cli

        return run_cli(args)
    from jaxanom.demo import DemoConfig, run_demo

    config = DemoConfig.quick() if args.quick else DemoConfig()
    if args.steps is not None:
        experiment = config.experiment
        config = dataclasses.replace(config, experiment=dataclasses.replace(
            experiment, train=dataclasses.replace(experiment.train, steps=args.steps)))
    run_demo(out_folder(args.out, args.overwrite), config, progress=not args.no_progress)
