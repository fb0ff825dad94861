"""``jaxanom predict``: anomaly maps of image files (npy, png, SegmentMeIfYouCan's hdf5 tree)."""
from __future__ import annotations

from jaxanom.cli.common import METHOD_OPTIONS, add_common, add_config, add_methods, positive_int, size_hw
from jaxanom.errors import InputError


def add_parser(commands) -> None:
    from jaxanom.app.commands.predict import FORMATS, SMIYC_DATASETS

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
    parser.add_argument("--size", help="working size HxW the network sees, e.g. `--size 512x1024` (default: each "
                        "image's own size); maps are resized back to the image's size")
    parser.add_argument("--batch-size", type=positive_int, default=1,
                        help="images sent to the device before the first is read back; each is scored alone, so "
                        "the maps do not depend on it (default: 1)")
    parser.add_argument("--threads", type=positive_int,
                        help="host threads decoding the next images and as many writing maps, beside the device; "
                        "1 does all in one thread; the maps do not depend on it (default: half the CPUs, at most 8)")
    parser.add_argument("--dataset", help="SegmentMeIfYouCan dataset name for --format smiyc, e.g. "
                        "`--format smiyc --dataset AnomalyTrack-all`; one of " + ", ".join(SMIYC_DATASETS))
    parser.add_argument("--slic-step", type=positive_int,
                        help="SLIC grid step of the *_superpixel methods, the same as --set methods.M.slic_step=... for "
                        "each of them (default: ~2048 superpixels per image)")
    parser.add_argument("--cudam-sigma", type=float, help="CuDAM ensemble weight, the same as --set "
                        "methods.cudam.cudam_sigma=... (default: paper-equivalent)")
    parser.add_argument("--unit-interval", metavar="CENTER,SCALE",
                        help="write 1 / (1 + exp(-(score - CENTER) / SCALE)) in [0, 1] instead of each score (the "
                        "benchmark documents scores in [0, 1]); AP / AUROC / FPR keep their values, float16 ties do not")
    add_config(parser, set_help="set one of predict's settings by its name, after the flags, e.g. `--set batch_size=2`: "
               "methods, formats, size (HEIGHT,WIDTH, e.g. size=512,1024), batch_size, dataset, unit_interval "
               f"(CENTER,SCALE), threads; or {METHOD_OPTIONS}; a rerun with other options recomputes (--overwrite) or "
               "refuses the maps")
    add_common(parser, progress=True)
    parser.set_defaults(handler=run, aliases={"formats": "format", "plugins": "plugin", "overrides": "set"})


def run(args) -> None:
    from jaxanom.app.commands.predict import predict

    predict(args.images, run=args.run, out=args.out, methods=args.methods, plugins=args.plugin, stats=args.stats,
            formats=args.format, size=size_hw(args.size), batch_size=args.batch_size, dataset=args.dataset,
            slic_step=args.slic_step, cudam_sigma=args.cudam_sigma, unit_interval=_pair(args.unit_interval),
            threads=args.threads, overrides=args.set, overwrite=args.overwrite, progress=not args.no_progress)


def _pair(text: str | None) -> tuple[float, float] | None:
    """``--unit-interval``'s (center, scale), checked by ``PredictSettings``."""
    if text is None:
        return None
    try:
        center, scale = (float(x) for x in text.split(","))
    except ValueError:
        raise InputError("unit_interval", f": expected CENTER,SCALE (two numbers), got {text!r}") from None
    return center, scale
