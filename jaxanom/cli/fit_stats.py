"""``jaxanom fit-stats``: SML class statistics (Eqs. 3-4) of a trained run."""
from __future__ import annotations

import os
import sys
from pathlib import Path

from jaxanom.cli.common import CLAIM, CommandError, add_common, check_out_outside, claim, positive_int, size_hw
from jaxanom.sml.policy import DEFAULT_POLICY, DEFAULT_STRENGTH, POLICIES

_LIBRARY_ADVICE = 'pass missing="pooled" or a policy ("min_count", "shrink")'  # sml.policy.finalize's
_FLAG_ADVICE = "pass --missing pooled, or --policy min_count or shrink"


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
                        "only: the statistics need no labels) instead of the run's training data, e.g. for a network "
                        "from convert-weights")
    parser.add_argument("--size", help="HxW the frames are resized to first, e.g. 512x1024 (default: as read)")
    parser.add_argument("--out", required=True, help="output .npz file")
    parser.add_argument("--missing", choices=["error", "pooled"], default="error",
                        help="policy none: classes never predicted fail, or use the pooled statistics "
                        "(default: %(default)s)")
    add_policy(parser)
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def add_policy(parser) -> None:
    """``--policy``, ``--min-count``, ``--strength`` (``jaxanom.sml.stats_finalize``)."""
    parser.add_argument("--policy", choices=POLICIES, default=DEFAULT_POLICY,
                        help="scarce classes: the original's estimate (none), the pooled statistics below "
                        "--min-count pixels (min_count), or shrinkage toward the pooled statistics with a prior "
                        "of --strength pixels (shrink) (default: %(default)s)")
    parser.add_argument("--min-count", type=float, default=10_000,
                        help="pixels below which a class is scarce: pooled by min_count, warned about always "
                        "(default: %(default)g)")
    parser.add_argument("--strength", type=float, default=DEFAULT_STRENGTH,
                        help="shrink: the pooled prior's weight in pixels (default: %(default)g)")


def stats_table(final) -> str:
    """Per-class lines: pixels, mean, std, status (and the prior's weight when shrunk)."""
    lines = ["class   pixels       mean      std  status"]
    for c, (n, m, s, status, w) in enumerate(zip(final.count, final.mean, final.std, final.status,
                                                 final.prior_weight)):
        extra = f" (prior weight {w:.2f})" if status == "shrunk" else ""
        lines.append(f"{c:5d} {n:8d} {float(m):10.4f} {float(s):8.4f}  {status}{extra}")
    return "\n".join(lines)


class OneSize:
    """The frames of a random-access source, ValueError naming ``what`` and ``--size`` when one's size
    differs from the first's (frames are batched, and a batch holds frames of one size)."""

    def __init__(self, source, what: str):
        self.source, self.what, self.first = source, what, None

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, index: int) -> dict:
        frame = self.source[index]
        seen = (frame.get("name", str(index)), frame["image"].shape[:2])
        self.first = self.first or seen
        if seen[1] != self.first[1]:
            raise ValueError(f"{self.what}: frames differ in size ({self.first[0]} is {self.first[1][0]}x"
                             f"{self.first[1][1]}, {seen[0]} is {seen[1][0]}x{seen[1][1]}); pass --size HxW to "
                             "resize them to one")
        return frame


def run(args) -> None:
    from jaxanom import sml
    from jaxanom.data.pipeline import evaluation_batches
    from jaxanom.app.evaluate import class_statistics, predictor
    from jaxanom.app.experiment import build_network, frames, load_variables
    from jaxanom.data import Cityscapes
    from jaxanom.data.frames import FirstFrames, Resized
    from jaxanom.sml.policy import check_policy

    out = Path(args.out)
    if out.is_dir():
        raise CommandError(f"--out {out}: is a folder; expected the path of the .npz file to write")
    if args.out.endswith(("/", os.sep)):
        raise CommandError(f"--out {args.out}: names a folder; expected the path of the .npz file to write")
    if out.suffix != ".npz":
        raise CommandError(f"--out {args.out}: expected a file name ending in .npz (what --stats reads)")
    check_out_outside(args.out, {"--run": args.run})
    if out.exists() and not args.overwrite:
        raise CommandError(f"--out {out}: file exists; choose another or pass --overwrite")
    try:
        check_policy(args.policy, args.min_count, args.strength)
    except ValueError as error:
        raise CommandError(f"--policy, --min-count, --strength: {error}") from None
    size = size_hw(args.size)
    experiment, variables = load_variables(args.run)
    if args.cityscapes:  # the statistics use the network's predictions only: no labels read
        source = FirstFrames(Cityscapes(args.cityscapes, "train", with_labels=False), args.frames)
    else:
        source = frames(experiment, "train", args.frames)
    if size is not None:
        source = Resized(source, *size)
    elif args.cityscapes:
        source = OneSize(source, f"--cityscapes {args.cityscapes}")
    out.parent.mkdir(parents=True, exist_ok=True)
    claim(out.parent / f"{out.name}{CLAIM}", f"--out {out}")
    batches = evaluation_batches(source, batch_size=experiment.batch_size)
    predict = predictor(build_network(experiment), variables)
    stats = class_statistics(predict, batches)
    try:
        final = sml.stats_finalize_report(stats, missing=args.missing, policy=args.policy,
                                          min_count=args.min_count, strength=args.strength)
    except ValueError as error:  # the library names its arguments; say the flags instead
        raise CommandError(str(error).replace(_LIBRARY_ADVICE, _FLAG_ADVICE)
                           .replace("use a smaller strength", "use a smaller --strength")) from None
    policy = {"policy": args.policy, "missing": args.missing, "min_count": args.min_count,
              "strength": args.strength, "frames": len(source)}
    sml.save_stats(out, final.mean, final.std, final.count, status=final.status, policy=policy)
    print(stats_table(final))
    scarce = [c for c, n in enumerate(final.count) if n < args.min_count]
    if scarce:
        print(f"jaxanom fit-stats: warning: classes {scarce} have fewer than {args.min_count:g} predicted pixels "
              f"(counts {[int(final.count[c]) for c in scarce]}); their statistics are "
              f"{'unreliable (consider --policy shrink or min_count)' if args.policy == 'none' else 'pooled or shrunk as the table says'}",
              file=sys.stderr)
    print(f"statistics of {len(final.mean)} classes from {policy['frames']} frames, policy {args.policy} -> {out}")
