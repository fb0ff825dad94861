"""``jaxanom fit-stats``: SML class statistics (Eqs. 3-4) of a trained run."""
from __future__ import annotations

from pathlib import Path

from jaxanom.cli.common import CLAIM, CommandError, add_common, claim, positive_int


def add_parser(commands) -> None:
    parser = commands.add_parser("fit-stats", help="fit SML class statistics of a trained run",
                                 description="Stream a trained network's logits over training frames and write the "
                                 "per-class max-logit mean / std (SML Eqs. 3-4) as .npz.")
    parser.add_argument("--run", required=True, help="training run folder")
    parser.add_argument("--frames", type=positive_int, default=200,
                        help="training frames to use, at most the run's (default: %(default)s)")
    parser.add_argument("--out", required=True, help="output .npz file")
    parser.add_argument("--missing", choices=["error", "pooled"], default="error",
                        help="classes never predicted: fail, or use the pooled statistics (default: %(default)s)")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    from jaxanom import sml
    from jaxanom.data.pipeline import evaluation_batches
    from jaxanom.evaluate import class_statistics, predictor
    from jaxanom.experiment import build_network, frames, load_variables

    out = Path(args.out)
    if out.is_dir():
        raise CommandError(f"--out {out}: is a folder; expected the path of the .npz file to write")
    if out.exists() and not args.overwrite:
        raise CommandError(f"--out {out}: file exists; choose another or pass --overwrite")
    experiment, variables = load_variables(args.run)
    source = frames(experiment, "train", args.frames)
    out.parent.mkdir(parents=True, exist_ok=True)
    claim(out.parent / f"{out.name}{CLAIM}", f"--out {out}")
    batches = evaluation_batches(source, batch_size=experiment.batch_size)
    predict = predictor(build_network(experiment), variables)
    stats = class_statistics(predict, batches)
    mean, std = sml.stats_finalize(stats, missing=args.missing)
    sml.save_stats(out, mean, std, stats.count)
    print(f"statistics of {len(mean)} classes from {len(source)} frames -> {out}")
