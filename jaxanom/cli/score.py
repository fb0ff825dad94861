"""``jaxanom score``: scores and metrics from logits saved by another framework (``jaxanom.app.commands.score``)."""
from __future__ import annotations

from jaxanom.cli.common import METHOD_OPTIONS, add_common, add_config, add_evaluators, add_scoring


def add_parser(commands) -> None:
    parser = commands.add_parser("score", help="scores and metrics from logits saved by another framework",
                                 description="Read logits (.npy, or .npz with array `logits`) of shape (N, C, H, W) "
                                 "or (N, H, W, C), and optional labels (N, H, W) in {0, 1, 255}; write score maps "
                                 "(scores/<method>.npy, float32 (N, H, W)) and, with labels, the metrics.")
    parser.add_argument("--logits", required=True, help=".npy or .npz file of logits")
    parser.add_argument("--layout", choices=["NCHW", "NHWC"], default="NCHW",
                        help="logits layout (default: %(default)s)")
    parser.add_argument("--any-layout", action="store_true",
                        help="accept more classes than pixels along H or W (refused otherwise: a sign of a "
                        "wrong --layout)")
    parser.add_argument("--labels", help=".npy or .npz file (array `labels`) of anomaly labels")
    add_scoring(parser)
    add_evaluators(parser, " (with --labels)")
    add_config(parser, set_help=f"{METHOD_OPTIONS}; the options each method used are in metrics.json")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run, aliases={"plugins": "plugin", "overrides": "set"})


def run(args) -> None:
    from jaxanom.app.commands.score import score

    score(logits=args.logits, out=args.out, layout=args.layout, any_layout=args.any_layout, labels=args.labels,
          stats=args.stats, methods=args.methods, plugins=args.plugin, fpr_convention=args.fpr_convention,
          ap_convention=args.ap_convention, evaluators=args.evaluators, overrides=args.set, overwrite=args.overwrite)
