"""``jaxanom score``: scores and metrics from logits saved by another framework.

Streams: the logits (and labels) are read one image at a time (a .npy file is memory-mapped,
an .npz member decompressed sequentially), each image is scored and added to the exact metric
accumulators, and its score maps are appended to ``scores/<method>.npy`` files that appear
only once complete. Memory: one image's logits and scores, plus the accumulators' ~6 bytes per
distinct score (see ``jaxanom.metrics.accumulator``).
"""
from __future__ import annotations

from jaxanom.cli.common import (DEFAULT_METHODS, CommandError, StreamedArray, add_common, add_scoring, load_plugins,
                                load_stats, out_folder)


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
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    import contextlib

    import numpy as np

    from jaxanom.app import scoring
    from jaxanom.app.reports import results_table
    from jaxanom.io import NpyWriter, write_json_atomic
    from jaxanom.metrics import AnomalyMetricAccumulator

    load_plugins(args)
    logits = StreamedArray(args.logits, "logits")
    if logits.ndim != 4:
        raise CommandError(f"--logits: expected 4 dimensions ({args.layout}), got shape {logits.shape}")
    channels_first = args.layout == "NCHW"
    size = (logits.shape[2:] if channels_first else logits.shape[1:3])
    classes = logits.shape[1] if channels_first else logits.shape[3]
    if classes > min(size) and not args.any_layout:
        raise CommandError(f"--logits: with --layout {args.layout}, shape {logits.shape} has {classes} classes but "
                           f"images of {size[0]} x {size[1]} pixels; check --layout, or pass --any-layout if so")
    labels = None if args.labels is None else StreamedArray(args.labels, "labels")
    shape = (len(logits), *size)
    if labels is not None and labels.shape != shape:
        raise CommandError(f"--labels: expected shape {shape} (N, H, W) to match the logits, got {labels.shape}")
    stats = load_stats(args.stats)
    if stats is not None and len(stats[0]) != classes:
        raise CommandError(f"--stats: has {len(stats[0])} classes, the logits have {classes}")
    names = scoring.check((args.methods or DEFAULT_METHODS).split(","),
                          scoring.provided(classes=classes, stats=stats is not None))
    out = out_folder(args.out, args.overwrite)
    accumulators = {name: AnomalyMetricAccumulator() for name in names}
    label_images = iter(labels if labels is not None else ())
    with contextlib.ExitStack() as files:
        writers = {name: files.enter_context(NpyWriter(out / "scores" / f"{name}.npy", shape, np.float32))
                   for name in names}
        for index, image in enumerate(logits):
            image = np.moveaxis(image, 0, -1) if channels_first else image
            label = None if labels is None else next(label_images)
            try:
                scores, _ = scoring.score_all(names, scoring.inputs_of({"logits": image[None]}, stats))
                scores = {name: np.asarray(score)[0] for name, score in scores.items()}
                if label is not None:
                    for name, score in scores.items():
                        accumulators[name].update(score, label)
            except ValueError as error:
                raise CommandError(f"image {index}: {error}") from None
            for name, score in scores.items():
                writers[name].write(score)
    print(f"score maps of {len(logits)} images -> {out / 'scores'}/<method>.npy")
    if labels is not None:
        metrics = {name: accumulators.pop(name).compute(fpr_convention=args.fpr_convention or "first",  # freed in turn
                                                        ap_convention=args.ap_convention) for name in names}
        write_json_atomic(out / "metrics.json", {"metrics": metrics})
        print(results_table(metrics))
