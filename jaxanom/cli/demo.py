"""``jaxanom demo``: train, fit SML statistics and evaluate on synthetic scenes."""
from __future__ import annotations

import dataclasses

from jaxanom.cli.common import CommandError, add_common, add_config, out_folder, positive_int, read_config, with_set


def add_parser(commands) -> None:
    parser = commands.add_parser("demo", help="train, fit SML statistics and evaluate on synthetic scenes",
                                 description="Train a small DeepLabV3+ with CuDAM on synthetic driving scenes, fit "
                                 "SML statistics, evaluate MSP / max logit / entropy / energy / SML / SML + "
                                 "post-processing / CuDAM on a synthetic anomaly split; write a table, "
                                 "results.json and pictures.")
    parser.add_argument("paper", nargs="?", choices=["mmf", "offroad"],
                        help="another paper's demo instead: mmf (multi-mechanism fusion, jaxanom.app.demos.mmf) or "
                        "offroad (active + contrastive off-road segmentation, jaxanom.app.demos.offroad)")
    parser.add_argument("--out", default="jaxanom-demo", help="output folder (default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run of the same path at tiny sizes (minutes on a CPU, mostly compiling)")
    parser.add_argument("--steps", type=positive_int, help="training steps (default: 1500; --quick: 3)")
    parser.add_argument("--synthesizer", choices=["class_mean", "spade"],
                        help="mmf: the resynthesis (default: class_mean)")
    add_config(parser, "the demo's configuration (DemoConfig, MMFDemoConfig or OffroadDemoConfig): a JSON file of "
               "any of its fields, e.g. a results.json of the same demo, or a Python file defining `config`")
    add_common(parser, progress=True)
    parser.set_defaults(handler=run)


def run(args) -> None:
    if args.paper == "offroad":
        return run_offroad(args)
    if args.paper == "mmf":
        return run_mmf(args)
    from jaxanom.app.demos.sml_cudam import DemoConfig, run_demo

    config = _config(args, DemoConfig)
    if args.steps is not None:
        experiment = config.experiment
        config = dataclasses.replace(config, experiment=dataclasses.replace(
            experiment, train=dataclasses.replace(experiment.train, steps=args.steps)))
    config = with_set(config, args)  # checked before the output folder is claimed
    run_demo(out_folder(args.out, args.overwrite), config, progress=not args.no_progress)


def _config(args, cls):
    """``--config``'s ``cls``, else ``--quick``'s or the default one."""
    if args.quick and args.config:
        raise CommandError("--quick, --config: give one of them")
    return read_config(args.config, cls) if args.config else cls.quick() if args.quick else cls()


def run_mmf(args) -> None:
    """``jaxanom demo mmf [--quick | --config FILE] [--steps N] [--out DIR] [--overwrite]`` (N: segmenter steps)."""
    from jaxanom.app.demos.mmf import MMFDemoConfig, run_mmf_demo

    config = _config(args, MMFDemoConfig)
    if args.steps is not None:
        seg = config.pipeline.segmenter
        seg = dataclasses.replace(seg, train=dataclasses.replace(seg.train, steps=args.steps))
        config = dataclasses.replace(config, pipeline=dataclasses.replace(config.pipeline, segmenter=seg))
    if getattr(args, "synthesizer", None):
        pipeline = dataclasses.replace(config.pipeline, synthesizer=args.synthesizer)
        config = dataclasses.replace(config, pipeline=pipeline)
    config = with_set(config, args)  # checked before the output folder is claimed
    run_mmf_demo(out_folder(args.out, args.overwrite), config, progress=not args.no_progress)


def run_offroad(args) -> None:
    """``jaxanom demo offroad [--quick] [--steps N] [--config FILE] [--out DIR]``."""
    from jaxanom.app.demos.offroad import OffroadDemoConfig, run_offroad_demo

    config = _config(args, OffroadDemoConfig)
    if args.steps is not None:
        encoder = dataclasses.replace(config.pipeline.encoder, steps=args.steps)
        config = dataclasses.replace(config, pipeline=dataclasses.replace(config.pipeline, encoder=encoder))
    out = "jaxanom-demo-offroad" if args.out == "jaxanom-demo" else args.out
    config = with_set(config, args)  # checked before the output folder is claimed
    run_offroad_demo(out_folder(out, args.overwrite), config, progress=not args.no_progress)
