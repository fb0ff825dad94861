"""``jaxanom predict``: anomaly maps of image files (npy, png, SegmentMeIfYouCan's hdf5 tree)."""
from __future__ import annotations

from jaxanom.cli.common import (DEFAULT_METHODS, CommandError, add_common, add_config, add_methods, load_plugins,
                                load_stats, out_folder, positive_int, size_hw, with_set)


def add_parser(commands) -> None:
    from jaxanom.app.predict import FORMATS, SMIYC_DATASETS

    parser = commands.add_parser(
        "predict", help="anomaly maps of images (files, folders, globs) with a trained or converted run",
        description="Score JPEG / PNG / WebP images of any size with each method and write one map per image and "
        "method at the image's own size: npy/<method>/<frame>.npy (float16), png/<method>/<frame>.png (a picture "
        "with a colour bar), anomaly_p/<method>/<dataset>/<frame>.hdf5 (SegmentMeIfYouCan's submission tree, "
        "float16 in HDF5 dataset 'value'; needs h5py: pip install 'jaxanom[smiyc]'). <frame> is the image's "
        "file name without its extension, as given (a link's own name, not its target's). A rerun with the same settings, network weights and statistics skips the frames "
        "already written (one with others is refused; --overwrite recomputes every frame). Images under --out "
        "are left out.")
    parser.add_argument("images", nargs="+", help="image files, folders (their images) or quoted glob patterns")
    parser.add_argument("--run", required=True, help="run folder (train or convert-weights); read only")
    parser.add_argument("--out", required=True, help="output folder")
    add_methods(parser, unavailable=("mmf_maps",))  # no MMF pipeline here
    parser.add_argument("--stats", help="SML statistics .npz (from fit-stats); needed by the sml* and cudam methods")
    parser.add_argument("--format", default="npy", help=f"comma-separated, from {', '.join(FORMATS)} "
                        "(default: %(default)s)")
    parser.add_argument("--size", help="working size HxW the network sees, e.g. 512x1024 (default: each image's "
                        "own size); maps are resized back to the image's size")
    parser.add_argument("--batch-size", type=positive_int, default=1,
                        help="images sent to the device before the first is read back; each is scored alone, so "
                        "the maps do not depend on it (default: 1)")
    parser.add_argument("--dataset", help=f"SegmentMeIfYouCan dataset name for --format smiyc, e.g. "
                        f"{', '.join(SMIYC_DATASETS)}")
    parser.add_argument("--slic-step", type=positive_int,
                        help="SLIC grid step of the *_superpixel methods (default: ~2048 superpixels per image)")
    parser.add_argument("--cudam-sigma", type=float, help="CuDAM ensemble weight (default: paper-equivalent)")
    parser.add_argument("--unit-interval", metavar="CENTER,SCALE",
                        help="write 1 / (1 + exp(-(score - CENTER) / SCALE)) in [0, 1] instead of each score (the "
                        "benchmark documents scores in [0, 1]); AP / AUROC / FPR keep their values, float16 ties do not")
    add_config(parser)  # the PredictSettings, e.g. --set size=512,1024
    add_common(parser, progress=True)
    parser.set_defaults(handler=run)


def run(args) -> None:
    import json
    from pathlib import Path

    from jaxanom.app import scoring
    from jaxanom.app.evaluate import predictor
    from jaxanom.app.experiment import build_network, jsonable, load_experiment, load_variables
    from jaxanom.io import write_json_atomic
    from jaxanom.app.predict import (DeviceOutOfMemory, PredictSettings, Scorer, check_resumable, fingerprint, inside,
                                     list_images, logits_shape, predict_images, remove_other_maps, settings_record,
                                     size_check)

    load_plugins(args)
    settings = PredictSettings(methods=tuple((args.methods or DEFAULT_METHODS).split(",")),
                               formats=tuple(args.format.split(",")), size=size_hw(args.size),
                               batch_size=args.batch_size, dataset=args.dataset, slic_step=args.slic_step,
                               cudam_sigma=args.cudam_sigma, unit_interval=_pair(args.unit_interval))
    settings = with_set(settings, args)
    if "smiyc" in settings.formats:
        try:
            import h5py  # noqa: F401
        except ImportError:
            raise CommandError("--format smiyc: needs h5py (pip install 'jaxanom[smiyc]')") from None
    run_dir, out = Path(args.run), Path(args.out)
    paths, left_out = list_images(args.images, out)
    if not (run_dir / "experiment.json").is_file():
        raise CommandError(f"--run {run_dir}: expected a run folder (with experiment.json)")
    if inside(out, run_dir):
        raise CommandError(f"--out {out}: lies inside --run {run_dir}; predict never writes into a run")
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
    # the maps depend on what the files hold, not where they are: a moved run resumes, a re-fitted one does not
    network = fingerprint({"experiment": json.dumps(jsonable(experiment), sort_keys=True), "variables": variables})
    record = settings_record(settings, network=network, statistics=None if stats is None else fingerprint(stats),
                             read_from={"run": str(run_dir.resolve()),
                                        "stats": None if args.stats is None else str(Path(args.stats).resolve())})
    resuming = not args.overwrite and out.is_dir() and check_resumable(out, record)
    out = out_folder(args.out, args.overwrite or resuming, hint="pass --overwrite (or rerun with its settings)")
    if args.overwrite and (removed := remove_other_maps(out, record, settings)):
        print(f"jaxanom predict: removed {removed} maps of other settings, network or statistics from {out}")
    write_json_atomic(out / "settings.json", record)
    scorer = Scorer(predictor(model, variables), settings, stats, check_size=None if settings.size else check)
    try:
        summary = predict_images(paths, out, scorer, progress=not args.no_progress, redo=args.overwrite)
    except DeviceOutOfMemory as error:
        raise CommandError(f"{error}; rerun with a smaller --batch-size to resume, or a smaller --size "
                           "(into another --out, or with --overwrite)") from None
    skipped = f", {left_out} images under --out left out" if left_out else ""
    print(f"jaxanom predict: {summary['written']} frames written, {summary['skipped']} already there{skipped}, "
          f"{len(settings.methods)} methods, formats {','.join(settings.formats)} -> {out}")


def _pair(text: str | None) -> tuple[float, float] | None:
    """``--unit-interval``'s (center, scale), checked by ``PredictSettings``."""
    if text is None:
        return None
    try:
        center, scale = (float(x) for x in text.split(","))
    except ValueError:
        raise CommandError(f"--unit-interval: expected CENTER,SCALE (two numbers), got {text!r}") from None
    return center, scale
