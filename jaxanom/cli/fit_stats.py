"""``jaxanom fit-stats``: SML class statistics (Eqs. 3-4) of a trained run."""
from __future__ import annotations

from jaxanom.cli.common import add_common, add_plugin, add_protocol, positive_int, size_hw


def add_parser(commands) -> None:
    parser = commands.add_parser("fit-stats", help="fit SML class statistics of a trained run",
                                 description="Stream a trained network's logits over training frames and write the "
                                 "per-class max-logit mean / std (SML Eqs. 3-4) as .npz. Prints a per-class table "
                                 "(pixels, mean, std, fitted / pooled / shrunk) and warns on scarce classes.")
    parser.add_argument("--run", required=True, help="training run folder")
    parser.add_argument("--frames", type=positive_int, default=200,
                        help="training frames to use, at most the run's (default: %(default)s)")
    parser.add_argument("--cityscapes", metavar="DIR",
                        help="fit on the train split of this Cityscapes folder (official layout; its leftImg8bit/ "
                        "only: the statistics need no labels) instead of the run's training data; needed for a "
                        "network from convert-weights, which has none")
    parser.add_argument("--size", help="HxW the frames are resized to first, e.g. `--size 512x1024` (default: as read)")
    add_protocol(parser, "fit as evaluate --protocol scores, so the statistics have one class per output the "
                 "methods see (erfnet-community resizes the frames to 512x1024 and drops a void output)")
    parser.add_argument("--out", required=True, help="output .npz file")
    parser.add_argument("--missing", choices=["error", "pooled"], default="error",
                        help="policy none: classes never predicted fail, or use the pooled statistics "
                        "(default: %(default)s)")
    add_policy(parser)
    add_plugin(parser)
    add_common(parser, progress=False)
    parser.set_defaults(handler=run, aliases={"plugins": "plugin"})


def add_policy(parser) -> None:
    """``--policy``, ``--min-count``, ``--strength`` (``jaxanom.sml.stats_finalize``)."""
    from jaxanom.app.commands.fit_stats import DEFAULT_POLICY, DEFAULT_STRENGTH, POLICIES

    parser.add_argument("--policy", choices=POLICIES, default=DEFAULT_POLICY,
                        help="scarce classes: the original's estimate (none), the pooled statistics below "
                        "--min-count pixels (min_count), or shrinkage toward the pooled statistics with a prior "
                        "of --strength pixels (shrink) (default: %(default)s)")
    parser.add_argument("--min-count", type=float, default=10_000,
                        help="pixels below which a class is scarce: pooled by min_count, warned about always "
                        "(default: %(default)g)")
    parser.add_argument("--strength", type=float, default=DEFAULT_STRENGTH,
                        help="shrink: the pooled prior's weight in pixels (default: %(default)g)")


def run(args) -> None:
    from jaxanom.app.commands.fit_stats import fit_stats

    fit_stats(run=args.run, out=args.out, frames=args.frames, cityscapes=args.cityscapes, size=size_hw(args.size),
              missing=args.missing, policy=args.policy, min_count=args.min_count, strength=args.strength,
              protocol=args.protocol, plugins=args.plugin, overwrite=args.overwrite)
