"""``jaxanom evaluate``: pooled anomaly metrics of a trained run on an anomaly dataset."""
from __future__ import annotations

from jaxanom.cli.common import CommandError, add_common, add_scoring, load_stats, out_folder

DATASETS = {
    "synthetic": "synthetic anomaly split (PATH = split name: anomaly, anomaly_small, anomaly_large)",
    "road-anomaly": "Road Anomaly (PATH holds frames/ and frame_list.json)",
    "smiyc": "SegmentMeIfYouCan RoadAnomaly21 / RoadObstacle21 (PATH holds images/, labels_masks/)",
    "fishyscapes-laf": "Fishyscapes Lost & Found (PATH = masks folder; --base = Lost & Found root)",
    "fishyscapes-static": "Fishyscapes Static (PATH = masks folder; --base = Cityscapes root)",
}


def add_parser(commands) -> None:
    parser = commands.add_parser("evaluate", help="score an anomaly dataset with a trained run",
                                 description="Pooled AP / AUROC / FPR@95 per method on an anomaly dataset. "
                                 "Datasets: " + "; ".join(f"{k}: {v}" for k, v in DATASETS.items()))
    parser.add_argument("--run", required=True, help="training run folder")
    parser.add_argument("--dataset", required=True, choices=list(DATASETS))
    parser.add_argument("--path", required=True, help="dataset folder (see the list above)")
    parser.add_argument("--base", help="base dataset root (Fishyscapes only)")
    parser.add_argument("--frames", type=int, default=64, help="synthetic frames (default: %(default)s)")
    add_scoring(parser)
    parser.add_argument("--cudam-sigma", type=float,
                        help="CuDAM ensemble weight (Eq. 10); default: the paper's 2e4 rescaled to the attention "
                        "map's size (equivalent_weight), recorded in metrics.json")
    parser.add_argument("--pictures", type=int, default=0, help="frames to draw (default: %(default)s)")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def anomaly_source(args):
    """The dataset reader that ``--dataset``, ``--path`` and ``--base`` name."""
    from jaxanom import data

    if args.dataset == "synthetic":
        return data.SyntheticScenes(args.path, args.frames, seed=1)
    if args.dataset == "road-anomaly":
        return data.RoadAnomaly(args.path)
    if args.dataset == "smiyc":
        return data.SegmentMeIfYouCan(args.path)
    if not args.base:
        raise CommandError(f"--base: the {args.dataset} dataset needs the root of its base images")
    reader = data.FishyscapesLostAndFound if args.dataset == "fishyscapes-laf" else data.FishyscapesStatic
    return reader(args.path, args.base)


def run(args) -> None:
    from jaxanom.data.pipeline import evaluation_batches
    from jaxanom.demo import results_table
    from jaxanom.evaluate import anomaly_results, predictions, predictor
    from jaxanom.experiment import build_network, load_variables
    from jaxanom.io import write_json_atomic

    source = anomaly_source(args)
    stats = load_stats(args.stats)
    out = out_folder(args.out, args.overwrite)
    experiment, variables = load_variables(args.run)
    predict = predictor(build_network(experiment), variables)
    names = args.methods.split(",")
    batches = evaluation_batches(source, batch_size=1)
    metrics, _ = anomaly_results(predictions(predict, batches), names, stats=stats, cudam_sigma=args.cudam_sigma,
                                 fpr_convention=args.fpr_convention, ap_convention=args.ap_convention)
    record = {"dataset": args.dataset, "path": args.path, "frames": len(source), "metrics": metrics}
    if stats is not None:
        record["sml_statistics"] = statistics_record(args.stats)
    if "cudam" in metrics:
        record["cudam_sigma"] = {"values": metrics["cudam"]["sigma"],
                                 "source": "given" if args.cudam_sigma is not None else "paper-equivalent"}
    write_json_atomic(out / "metrics.json", record)
    if args.pictures:
        from jaxanom.demo import write_pictures

        write_pictures(out, predict, source, stats, args.pictures)
    print(results_table(metrics))


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
