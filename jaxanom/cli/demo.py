"""``jaxanom demo``: train, fit SML statistics and evaluate on synthetic scenes."""
from __future__ import annotations

from jaxanom.cli.common import add_common, add_config, add_plugin, positive_int


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
    add_config(parser, "experiment.train.optim.lr=1e-3", "the demo's configuration (DemoConfig, MMFDemoConfig or OffroadDemoConfig): a JSON file of "
               "any of its fields, e.g. a results.json of the same demo, or a Python file defining `config`")
    add_plugin(parser)
    add_common(parser, progress=True)
    parser.set_defaults(handler=run, aliases={"overrides": "set", "plugins": "plugin"})


def run(args) -> None:
    from jaxanom.app.commands.demo import demo

    demo(args.paper, out=args.out, quick=args.quick, steps=args.steps, config=args.config,
         synthesizer=args.synthesizer, plugins=args.plugin, overrides=args.set, overwrite=args.overwrite, progress=not args.no_progress)
