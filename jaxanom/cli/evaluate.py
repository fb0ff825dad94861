"""``jaxanom evaluate``: pooled anomaly metrics of a trained run on an anomaly dataset."""
from __future__ import annotations

from jaxanom.cli.common import (DEFAULT_METHODS, CommandError, add_common, add_scoring, check_out_outside, load_plugins,
                                load_stats, nonnegative_int, out_folder, positive_int)

from jaxanom.app.protocols import PROTOCOLS

DATASETS = {
    "synthetic": "synthetic anomaly split (PATH = split name: anomaly, anomaly_small, anomaly_large)",
    "road-anomaly": "Road Anomaly (PATH holds frames/ and frame_list.json)",
    "smiyc": "SegmentMeIfYouCan RoadAnomaly21 / RoadObstacle21 (PATH holds images/, labels_masks/)",
    "fishyscapes-laf": "Fishyscapes Lost & Found (PATH = masks folder; --base = Lost & Found root)",
    "fishyscapes-static": "Fishyscapes Static (PATH = masks folder; --base = Cityscapes root)",
    "lost-and-found": "Lost and Found (PATH = root with leftImg8bit/, gtCoarse/, disparity/; for --mmf)",
}
MMF_DEFAULT_METHODS = "entropy,resynthesis,resynthesis_post,mmf_raw,mmf"
# SegmentMeIfYouCan's component rules per dataset (smiyc: RoadAnomaly21 or RoadObstacle21, say which)
TRACKS = {"synthetic": "anomaly", "road-anomaly": "anomaly", "fishyscapes-laf": "anomaly",
          "fishyscapes-static": "anomaly", "lost-and-found": "obstacle", "smiyc": None}


def add_parser(commands) -> None:
    parser = commands.add_parser("evaluate", help="score an anomaly dataset with a trained run",
                                 description="Pooled AP / AUROC / FPR@95 per method on an anomaly dataset. "
                                 "Datasets: " + "; ".join(f"{k}: {v}" for k, v in DATASETS.items()))
    model = parser.add_mutually_exclusive_group(required=True)
    model.add_argument("--run", help="training run folder")
    model.add_argument("--mmf", help="an MMF pipeline: a folder written by `jaxanom demo mmf` (its results.json and "
                       f"runs/); frames need disparity; default methods {MMF_DEFAULT_METHODS}, in the road ROI "
                       "where the dataset has one")
    model.add_argument("--maps", help="a folder written by `jaxanom predict --format smiyc` (anomaly_p/<method>/"
                       "<dataset>/<frame>.hdf5, the SegmentMeIfYouCan submission tree, from any network): evaluate "
                       "those maps; default methods: every method folder")
    parser.add_argument("--dataset", required=True, choices=list(DATASETS))
    parser.add_argument("--path", required=True, help="dataset folder (see the list above)")
    parser.add_argument("--base", help="base dataset root (Fishyscapes only)")
    parser.add_argument("--depth", help="smiyc with --mmf: folder of <name>_disparity.png files (the tracks have none)")
    parser.add_argument("--frames", type=positive_int, default=64, help="synthetic frames (default: %(default)s)")
    add_scoring(parser)
    parser.add_argument("--cudam-sigma", type=float,
                        help="CuDAM ensemble weight (Eq. 10); default: the paper's 2e4 rescaled to the attention "
                        "map's size (equivalent_weight), recorded in metrics.json")
    parser.add_argument("--track", choices=["anomaly", "obstacle", "none"],
                        help="SegmentMeIfYouCan component metrics (sIoU, PPV, mean F1; pooled and per frame) with "
                        "the anomaly track's size rules (RoadAnomaly21, Road Anomaly, Fishyscapes) or the obstacle "
                        "track's (RoadObstacle21, Lost and Found); none: pixel metrics only. Default: the dataset's "
                        "track; smiyc needs it")
    parser.add_argument("--convention", choices=["exact", "smiyc"], default="exact",
                        help="exact (default): one curve point per distinct score; smiyc: AP, AUROC, FPR@95 and the "
                        "component threshold as the official SegmentMeIfYouCan kit computes them (float16 scores, "
                        "768 percentile bins per frame, mask score > t; the exact values stay in metrics.json)")
    parser.add_argument("--protocol", choices=list(PROTOCOLS), default="native",
                        help="how frames become counted pixels (with --run): " + "; ".join(
                            f"{p.name}: {p.description}" for p in PROTOCOLS.values()) + " (default: %(default)s)")
    parser.add_argument("--all-conventions", action="store_true",
                        help="also print AP (step, trapz, envelope) and FPR@95 (first, interp, nearest, strict) side "
                        "by side (metrics.json always holds them)")
    parser.add_argument("--pictures", type=nonnegative_int, default=0, help="frames to draw (default: %(default)s)")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    from jaxanom.app import scoring
    from jaxanom._validate import check_number
    from jaxanom.app.protocols import get_protocol
    from jaxanom.app.reports import conventions_table, results_table
    from jaxanom.app.demos.mmf import mmf_scored_batches
    from jaxanom.app.evaluate import anomaly_results, dataset_reader, predictor, protocol_predictions, saved_map_batches
    from jaxanom.app.experiment import build_network, load_experiment, load_variables
    from jaxanom.io import write_json_atomic

    track = args.track or TRACKS[args.dataset]
    if track is None:
        raise CommandError("--track: the smiyc dataset holds either track; pass --track anomaly (RoadAnomaly21) or "
                           "--track obstacle (RoadObstacle21)")
    check_out_outside(args.out, {"--run": args.run, "--mmf": args.mmf, "--maps": args.maps})
    protocol = get_protocol(args.protocol)
    if protocol.name != "native" and not args.run:
        raise CommandError(f"--protocol {protocol.name}: resizes the frames the network sees, so it needs --run")
    load_plugins(args)
    stats = load_stats(args.stats)
    if args.cudam_sigma is not None:
        check_number("--cudam-sigma", args.cudam_sigma, 0.0, open_low=True)
    options = {"cudam_sigma": args.cudam_sigma}
    if args.mmf:  # every check before the first frame is read or scored
        names = scoring.check((args.methods or MMF_DEFAULT_METHODS).split(","),
                              scoring.provided(classes=None, stats=stats is not None, mmf_maps=True), options)
        source, batches = mmf_scored_batches(args.mmf, args.dataset, args.path, frames=args.frames, depth=args.depth)
    elif args.maps:
        source = dataset_reader(args.dataset, args.path, base=args.base, frames=args.frames, depth=args.depth)
        try:
            names, batches = saved_map_batches(args.maps, source, args.methods.split(",") if args.methods else None)
        except FileNotFoundError as error:
            raise CommandError(f"--maps: {error}") from None
    else:  # the frames' images come with every batch (evaluation_batches)
        names = scoring.check((args.methods or DEFAULT_METHODS).split(","),
                              scoring.run_inputs(load_experiment(args.run), stats=stats is not None), options)
        source = dataset_reader(args.dataset, args.path, base=args.base, frames=args.frames, depth=args.depth)
        experiment, variables = load_variables(args.run)
        predict = predictor(build_network(experiment), variables)
    skipped: list[str] = []
    if args.run:
        batches = protocol_predictions(predict, source, protocol, skipped)
    out = out_folder(args.out, args.overwrite)
    metrics, _ = anomaly_results(batches, names, stats=stats, options=options,
                                 fpr_convention=args.fpr_convention or protocol.fpr_convention,
                                 ap_convention=args.ap_convention, track=None if track == "none" else track,
                                 spill_dir=out, convention=args.convention, drop_void=protocol.drop_void)
    record = {"dataset": args.dataset, "path": args.path, "frames": len(source), "convention": args.convention,
              "protocol": protocol.name, "metrics": metrics}
    if skipped:
        record["frames_skipped"] = skipped
    if args.mmf:
        record["mmf"] = args.mmf
    if args.maps:
        record["maps"] = args.maps
    if stats is not None:
        record["sml_statistics"] = statistics_record(args.stats)
    if "cudam" in metrics:
        record["cudam_sigma"] = {"values": metrics["cudam"]["options"]["cudam_sigma"],
                                 "source": "given" if args.cudam_sigma is not None else "paper-equivalent"}
    write_json_atomic(out / "metrics.json", record)
    if args.pictures and args.run:  # MMF's pictures: jaxanom demo mmf; maps': jaxanom predict --format png
        from jaxanom.app.reports import write_pictures

        write_pictures(out, predict, source, stats, args.pictures)
    if args.convention == "smiyc":
        print("The official SegmentMeIfYouCan kit's numbers (binned; the exact ones: metrics.json, \"exact\"):")
    print(results_table(metrics))
    if args.all_conventions:
        print("\n" + conventions_table(metrics))


def statistics_record(path: str) -> dict:
    """What ``metrics.json`` says about the SML statistics: file, policy, counts, pooled and shrunk classes."""
    from jaxanom.sml import load_stats, load_stats_info

    info = load_stats_info(path)
    record = {"file": path, "policy": info["policy"], "counts": load_stats(path)[2].tolist()}
    if info["status"] is None:
        record["classes"] = "unknown: the file has no per-class status (written without a policy)"
    else:
        record["classes"] = {s: [c for c, x in enumerate(info["status"]) if x == s] for s in ("pooled", "shrunk")}
    return record
