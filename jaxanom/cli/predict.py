"""``jaxanom predict``: anomaly maps of image files (npy, png, SegmentMeIfYouCan's hdf5 tree)."""
from __future__ import annotations

from jaxanom.cli.common import (DEFAULT_METHODS, CommandError, add_common, add_methods, load_plugins, load_stats,
                                out_folder, positive_int, size_hw)


def add_parser(commands) -> None:
    from jaxanom.app.predict import FORMATS, SMIYC_DATASETS

    parser = commands.add_parser(
        "predict", help="anomaly maps of images (files, folders, globs) with a trained or converted run",
        description="Score JPEG / PNG / WebP images of any size with each method and write one map per image and "
        "method at the image's own size: npy/<method>/<frame>.npy (float16), png/<method>/<frame>.png (a picture "
        "with a colour bar), anomaly_p/<method>/<dataset>/<frame>.hdf5 (SegmentMeIfYouCan's submission tree, "
        "float16 in HDF5 dataset 'value'; needs h5py: pip install 'jaxanom[smiyc]'). A rerun with the same "
        "settings skips the frames already written.")
    parser.add_argument("images", nargs="+", help="image files, folders (their images) or quoted glob patterns")
    parser.add_argument("--run", required=True, help="run folder (train or convert-weights); read only")
    parser.add_argument("--out", required=True, help="output folder")
    add_methods(parser, unavailable=("mmf_maps",))  # no MMF pipeline here
    parser.add_argument("--stats", help="SML statistics .npz (from fit-stats); needed by the sml* and cudam methods")
    parser.add_argument("--format", default="npy", help=f"comma-separated, from {', '.join(FORMATS)} "
                        "(default: %(default)s)")
    parser.add_argument("--size", help="working size HxW the network sees, e.g. 512x1024 (default: each image's "
                        "own size); maps are resized back to the image's size")
    parser.add_argument("--batch-size", type=positive_int, default=1, help="images per device batch (default: 1)")
    parser.add_argument("--dataset", help=f"SegmentMeIfYouCan dataset name for --format smiyc, e.g. "
                        f"{', '.join(SMIYC_DATASETS)}")
    parser.add_argument("--slic-step", type=positive_int,
                        help="SLIC grid step of the *_superpixel methods (default: ~2048 superpixels per image)")
    parser.add_argument("--cudam-sigma", type=float, help="CuDAM ensemble weight (default: paper-equivalent)")
    add_common(parser, progress=True)
    parser.set_defaults(handler=run)


def run(args) -> None:
    from pathlib import Path

    from jaxanom.app import scoring
    from jaxanom.app.evaluate import predictor
    from jaxanom.app.experiment import build_network, load_experiment, load_variables
    from jaxanom.io import write_json_atomic
    from jaxanom.app.predict import (PredictSettings, Scorer, check_resumable, inside, list_images, logits_shape,
                                 predict_images, settings_record, size_check)

    load_plugins(args)
    settings = PredictSettings(methods=tuple((args.methods or DEFAULT_METHODS).split(",")),
                               formats=tuple(args.format.split(",")), size=size_hw(args.size),
                               batch_size=args.batch_size, dataset=args.dataset, slic_step=args.slic_step,
                               cudam_sigma=args.cudam_sigma)
    if "smiyc" in settings.formats:
        try:
            import h5py  # noqa: F401
        except ImportError:
            raise CommandError("--format smiyc: needs h5py (pip install 'jaxanom[smiyc]')") from None
    paths = list_images(args.images)
    run_dir, out = Path(args.run), Path(args.out)
    if not (run_dir / "experiment.json").is_file():
        raise CommandError(f"--run {run_dir}: expected a run folder (with experiment.json)")
    if inside(out, run_dir):
        raise CommandError(f"--out {out}: lies inside --run {run_dir}; predict never writes into a run")
    if inside_out := [p for p in paths if inside(p, out)]:
        raise CommandError(f"images: {inside_out[0]} lies inside --out {out}")
    experiment = load_experiment(run_dir)
    stats = load_stats(args.stats)
    scoring.check(settings.methods, scoring.run_inputs(experiment, stats=stats is not None))
    model = build_network(experiment)
    _, variables = load_variables(run_dir)
    check = size_check(model, variables)
    if settings.size is not None:
        check(settings.size, "--size")
    if stats is not None:
        classes = logits_shape(model, variables, tuple(experiment.crop))[-1]
        if len(stats[0]) != classes:
            raise CommandError(f"--stats {args.stats}: has {len(stats[0])} classes, the network's logits {classes}")
    record = settings_record(settings, run=str(run_dir.resolve()),
                             stats=None if args.stats is None else str(Path(args.stats).resolve()))
    resuming = out.is_dir() and check_resumable(out, record)
    out = out_folder(args.out, args.overwrite or resuming, hint="pass --overwrite (or rerun with its settings)")
    write_json_atomic(out / "settings.json", record)
    scorer = Scorer(predictor(model, variables), settings, stats, check_size=None if settings.size else check)
    summary = predict_images(paths, out, scorer, progress=not args.no_progress)
    print(f"jaxanom predict: {summary['written']} frames written, {summary['skipped']} already there, "
          f"{len(settings.methods)} methods, formats {','.join(settings.formats)} -> {out}")
