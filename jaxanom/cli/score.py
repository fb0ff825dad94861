"""``jaxanom score``: scores and metrics from logits saved by another framework."""
from __future__ import annotations

from jaxanom.cli.common import CommandError, add_common, add_scoring, load_array, load_stats, out_folder


def add_parser(commands) -> None:
    parser = commands.add_parser("score", help="scores and metrics from logits saved by another framework",
                                 description="Read logits (.npy, or .npz with array `logits`) of shape (N, C, H, W) "
                                 "or (N, H, W, C), and optional labels (N, H, W) in {0, 1, 255}; write score maps "
                                 "(scores.npz) and, with labels, the metrics.")
    parser.add_argument("--logits", required=True, help=".npy or .npz file of logits")
    parser.add_argument("--layout", choices=["NCHW", "NHWC"], default="NCHW",
                        help="logits layout (default: %(default)s)")
    parser.add_argument("--labels", help=".npy or .npz file (array `labels`) of anomaly labels")
    add_scoring(parser)
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    import io

    import numpy as np

    from jaxanom import methods as scoring
    from jaxanom.demo import results_table
    from jaxanom.io import write_bytes_atomic, write_json_atomic
    from jaxanom.metrics import AnomalyMetricAccumulator

    logits = load_array(args.logits, "logits")
    if logits.ndim != 4:
        raise CommandError(f"--logits: expected 4 dimensions ({args.layout}), got shape {logits.shape}")
    if args.layout == "NCHW":
        logits = np.moveaxis(logits, 1, -1)
    labels = None if args.labels is None else load_array(args.labels, "labels")
    if labels is not None and labels.shape != logits.shape[:3]:
        raise CommandError(f"--labels: expected shape {logits.shape[:3]} (N, H, W) to match the logits, "
                           f"got {labels.shape}")
    stats = load_stats(args.stats)
    if stats is not None and len(stats[0]) != logits.shape[-1]:
        raise CommandError(f"--stats: has {len(stats[0])} classes, the logits have {logits.shape[-1]}")
    names = scoring.check_methods(args.methods.split(","), have_stats=stats is not None, have_attention=False)
    out = out_folder(args.out, args.overwrite)
    maps = {name: [] for name in names}
    accumulators = {name: AnomalyMetricAccumulator() for name in names}
    for index in range(len(logits)):
        for name in names:
            score = np.asarray(scoring.score_batch(name, logits[index:index + 1], stats=stats))
            maps[name].append(score[0])
            if labels is not None:
                accumulators[name].update(score[0], labels[index])
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{name: np.stack(m) for name, m in maps.items()})
    write_bytes_atomic(out / "scores.npz", buffer.getvalue())
    print(f"score maps of {len(logits)} images -> {out / 'scores.npz'}")
    if labels is not None:
        metrics = {name: acc.compute(fpr_convention=args.fpr_convention, ap_convention=args.ap_convention)
                   for name, acc in accumulators.items()}
        write_json_atomic(out / "metrics.json", {"metrics": metrics})
        print(results_table(metrics))
