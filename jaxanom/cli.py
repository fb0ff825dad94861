"""The ``jaxanom`` command: demo, train, fit-stats, evaluate, score.

Every command writes into an output folder that must be new or empty (``--overwrite`` allows
a non-empty one), and ends with a non-zero exit and a one-line reason on bad input.
"""
from __future__ import annotations

import argparse
import dataclasses
import runpy
import sys
from pathlib import Path

DATASETS = {
    "synthetic": "synthetic anomaly split (PATH = split name: anomaly, anomaly_small, anomaly_large)",
    "road-anomaly": "Road Anomaly (PATH holds frames/ and frame_list.json)",
    "smiyc": "SegmentMeIfYouCan RoadAnomaly21 / RoadObstacle21 (PATH holds images/, labels_masks/)",
    "fishyscapes-laf": "Fishyscapes Lost & Found (PATH = masks folder; --base = Lost & Found root)",
    "fishyscapes-static": "Fishyscapes Static (PATH = masks folder; --base = Cityscapes root)",
}


class CommandError(Exception):
    """Bad input to a command: printed as one line, exit status 2."""


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "handler"):
        parser.print_help()
        return 2
    try:
        args.handler(args)
    except (CommandError, ValueError, FileNotFoundError, FileExistsError) as error:
        print(f"jaxanom {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"jaxanom {args.command}: interrupted", file=sys.stderr)
        return 130
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxanom", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = commands.add_parser("demo", help="train, fit SML statistics and evaluate on synthetic scenes",
                               description="Train a small DeepLabV3+ with CuDAM on synthetic driving scenes, fit "
                               "SML statistics, evaluate MSP / max logit / entropy / energy / SML / SML + "
                               "post-processing / CuDAM on a synthetic anomaly split; write a table, "
                               "results.json and pictures.")
    demo.add_argument("--out", default="jaxanom-demo", help="output folder (default: %(default)s)")
    demo.add_argument("--quick", action="store_true", help="a seconds-long smoke run of the same path")
    demo.add_argument("--steps", type=int, help="training steps (default: 1500; --quick: 3)")
    _common(demo, progress=True)
    demo.set_defaults(handler=_demo)

    train = commands.add_parser("train", help="train a network (config file or flags); --resume continues",
                                description="Train a DeepLabV3+ (optionally with CuDAM or MSAAM). A config file is "
                                "a Python file that defines `experiment`, a jaxanom.experiment.Experiment; flags "
                                "override its fields.")
    train.add_argument("--out", required=True, help="run folder (checkpoints, logs, experiment.json); "
                       "must be new or empty unless --resume")
    train.add_argument("--config", help="Python file defining `experiment = Experiment(...)`")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    train.add_argument("--model", help="model preset, e.g. deeplabv3plus_tiny, deeplabv3plus_r101")
    train.add_argument("--attention", choices=["none", "cudam", "msaam"], help="attention module")
    train.add_argument("--data", choices=["synthetic", "cityscapes"], help="training data")
    train.add_argument("--data-root", help="dataset folder (Cityscapes layout)")
    train.add_argument("--steps", type=int, help="training steps")
    train.add_argument("--batch-size", type=int, help="global batch size")
    train.add_argument("--seed", type=int, help="random seed")
    _common(train, progress=True, overwrite=False)
    train.set_defaults(handler=_train)

    fit = commands.add_parser("fit-stats", help="fit SML class statistics of a trained run",
                              description="Stream a trained network's logits over training frames and write the "
                              "per-class max-logit mean / std (SML Eqs. 3-4) as .npz.")
    fit.add_argument("--run", required=True, help="training run folder")
    fit.add_argument("--frames", type=int, default=200, help="training frames to use (default: %(default)s)")
    fit.add_argument("--out", required=True, help="output .npz file")
    fit.add_argument("--missing", choices=["error", "pooled"], default="error",
                     help="classes never predicted: fail, or use the pooled statistics (default: %(default)s)")
    _common(fit, progress=False)
    fit.set_defaults(handler=_fit_stats)

    evaluate = commands.add_parser("evaluate", help="score an anomaly dataset with a trained run",
                                   description="Pooled AP / AUROC / FPR@95 per method on an anomaly dataset. "
                                   "Datasets: " + "; ".join(f"{k}: {v}" for k, v in DATASETS.items()))
    evaluate.add_argument("--run", required=True, help="training run folder")
    evaluate.add_argument("--dataset", required=True, choices=list(DATASETS))
    evaluate.add_argument("--path", required=True, help="dataset folder (see the list above)")
    evaluate.add_argument("--base", help="base dataset root (Fishyscapes only)")
    evaluate.add_argument("--frames", type=int, default=64, help="synthetic frames (default: %(default)s)")
    _scoring(evaluate)
    evaluate.add_argument("--pictures", type=int, default=0, help="frames to draw (default: %(default)s)")
    _common(evaluate, progress=False)
    evaluate.set_defaults(handler=_evaluate)

    score = commands.add_parser("score", help="scores and metrics from logits saved by another framework",
                                description="Read logits (.npy, or .npz with array `logits`) of shape (N, C, H, W) "
                                "or (N, H, W, C), and optional labels (N, H, W) in {0, 1, 255}; write score maps "
                                "(scores.npz) and, with labels, the metrics.")
    score.add_argument("--logits", required=True, help=".npy or .npz file of logits")
    score.add_argument("--layout", choices=["NCHW", "NHWC"], default="NCHW", help="logits layout (default: %(default)s)")
    score.add_argument("--labels", help=".npy or .npz file (array `labels`) of anomaly labels")
    _scoring(score)
    _common(score, progress=False)
    score.set_defaults(handler=_score)
    return parser


def _common(parser, progress: bool, overwrite: bool = True) -> None:
    if overwrite:
        parser.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty output folder")
    if progress:
        parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _scoring(parser) -> None:
    from jaxanom.methods import METHODS

    parser.add_argument("--stats", help="SML statistics .npz (from fit-stats); needed by the sml* and cudam methods")
    parser.add_argument("--methods", default="msp,max_logit,entropy,energy,sml,sml_post",
                        help=f"comma-separated, from {', '.join(METHODS)} (default: %(default)s)")
    parser.add_argument("--fpr-convention", choices=["first", "interp", "nearest", "strict"], default="first")
    parser.add_argument("--ap-convention", choices=["step", "trapz"], default="step")
    parser.add_argument("--out", required=True, help="output folder")


def _out_folder(path: str, overwrite: bool) -> Path:
    """An output folder that is new or empty, unless ``overwrite``."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise CommandError(f"--out {folder}: exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()) and not overwrite:
        raise CommandError(f"--out {folder}: folder exists and is not empty; choose another or pass --overwrite")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _demo(args) -> None:
    from jaxanom.demo import DemoConfig, run_demo

    config = DemoConfig.quick() if args.quick else DemoConfig()
    if args.steps is not None:
        experiment = config.experiment
        config = dataclasses.replace(config, experiment=dataclasses.replace(
            experiment, train=dataclasses.replace(experiment.train, steps=args.steps)))
    run_demo(_out_folder(args.out, args.overwrite), config, progress=not args.no_progress)


def _train(args) -> None:
    from jaxanom.experiment import Experiment, load_experiment, run_training

    out = Path(args.out)
    if args.resume:
        if args.config:
            raise CommandError("--resume continues the run's own experiment.json; do not pass --config")
        experiment = load_experiment(out)
    else:
        experiment = _load_config(args.config) if args.config else Experiment()
        _out_folder(args.out, overwrite=False)
    experiment = _override(experiment, args)
    run_training(experiment, out, progress=not args.no_progress)
    print(f"trained {experiment.train.steps} steps; checkpoints in {out / 'checkpoints'}")


def _load_config(path: str):
    from jaxanom.experiment import Experiment

    if not Path(path).is_file():
        raise CommandError(f"--config {path}: no such file")
    experiment = runpy.run_path(path).get("experiment")
    if not isinstance(experiment, Experiment):
        raise CommandError(f"--config {path}: expected it to define `experiment = Experiment(...)`, "
                           f"found {type(experiment).__name__}")
    return experiment


def _override(experiment, args):
    fields = {"model": args.model, "data": args.data, "data_root": args.data_root, "batch_size": args.batch_size}
    if args.attention is not None:
        fields["attention"] = None if args.attention == "none" else args.attention
    train = {"steps": args.steps, "seed": args.seed}
    train = {k: v for k, v in train.items() if v is not None}
    if "attention" in fields:
        method = {None: "plain"}.get(fields["attention"], fields["attention"])
        train["loss"] = dataclasses.replace(experiment.train.loss, method=method)
    fields = {k: v for k, v in fields.items() if v is not None or k == "attention"}
    return dataclasses.replace(experiment, **fields, train=dataclasses.replace(experiment.train, **train))


def _fit_stats(args) -> None:
    from jaxanom import sml
    from jaxanom.data.pipeline import evaluation_batches
    from jaxanom.evaluate import class_statistics, predictor
    from jaxanom.experiment import build_network, frames, load_variables

    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise CommandError(f"--out {out}: file exists; choose another or pass --overwrite")
    experiment, variables = load_variables(args.run)
    source = frames(experiment, "train", args.frames)
    batches = evaluation_batches(source, batch_size=experiment.batch_size)
    predict = predictor(build_network(experiment), variables)
    stats = class_statistics(predict, batches)
    mean, std = sml.stats_finalize(stats, missing=args.missing)
    out.parent.mkdir(parents=True, exist_ok=True)
    sml.save_stats(out, mean, std, stats.count)
    print(f"statistics of {len(mean)} classes from {min(args.frames, len(source))} frames -> {out}")


def _anomaly_source(args):
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


def _evaluate(args) -> None:
    from jaxanom.data.pipeline import evaluation_batches
    from jaxanom.demo import results_table
    from jaxanom.evaluate import anomaly_results, predictions, predictor
    from jaxanom.experiment import build_network, load_variables
    from jaxanom.io import write_json_atomic

    source = _anomaly_source(args)
    stats = _stats(args.stats)
    out = _out_folder(args.out, args.overwrite)
    experiment, variables = load_variables(args.run)
    predict = predictor(build_network(experiment), variables)
    names = args.methods.split(",")
    batches = evaluation_batches(source, batch_size=1)
    metrics, _ = anomaly_results(predictions(predict, batches), names, stats=stats,
                                 fpr_convention=args.fpr_convention, ap_convention=args.ap_convention)
    write_json_atomic(out / "metrics.json", {"dataset": args.dataset, "path": args.path, "frames": len(source),
                                             "metrics": metrics})
    if args.pictures:
        from jaxanom.demo import write_pictures

        write_pictures(out, predict, source, stats, args.pictures)
    print(results_table(metrics))


def _stats(path: str | None):
    if path is None:
        return None
    from jaxanom.sml import load_stats

    mean, std, _ = load_stats(path)
    return mean, std


def _load_array(path: str, name: str):
    import numpy as np

    file = Path(path)
    if not file.is_file():
        raise CommandError(f"--{name} {path}: no such file")
    try:
        loaded = np.load(file, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise CommandError(f"--{name} {path}: not a readable .npy/.npz file ({error})") from None
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            if name not in loaded.files:
                raise CommandError(f"--{name} {path}: expected an array named {name!r}, found {loaded.files}")
            return loaded[name]
    return loaded


def _score(args) -> None:
    import numpy as np

    from jaxanom import methods as scoring
    from jaxanom.demo import results_table
    from jaxanom.io import write_bytes_atomic, write_json_atomic
    from jaxanom.metrics import AnomalyMetricAccumulator

    logits = _load_array(args.logits, "logits")
    if logits.ndim != 4:
        raise CommandError(f"--logits: expected 4 dimensions ({args.layout}), got shape {logits.shape}")
    if args.layout == "NCHW":
        logits = np.moveaxis(logits, 1, -1)
    labels = None if args.labels is None else _load_array(args.labels, "labels")
    if labels is not None and labels.shape != logits.shape[:3]:
        raise CommandError(f"--labels: expected shape {logits.shape[:3]} (N, H, W) to match the logits, got {labels.shape}")
    stats = _stats(args.stats)
    if stats is not None and len(stats[0]) != logits.shape[-1]:
        raise CommandError(f"--stats: has {len(stats[0])} classes, the logits have {logits.shape[-1]}")
    names = scoring.check_methods(args.methods.split(","), have_stats=stats is not None, have_attention=False)
    out = _out_folder(args.out, args.overwrite)
    maps = {name: [] for name in names}
    accumulators = {name: AnomalyMetricAccumulator() for name in names}
    for index in range(len(logits)):
        for name in names:
            score = np.asarray(scoring.score_batch(name, logits[index:index + 1], stats=stats))
            maps[name].append(score[0])
            if labels is not None:
                accumulators[name].update(score[0], labels[index])
    import io

    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{name: np.stack(m) for name, m in maps.items()})
    write_bytes_atomic(out / "scores.npz", buffer.getvalue())
    print(f"score maps of {len(logits)} images -> {out / 'scores.npz'}")
    if labels is not None:
        metrics = {name: acc.compute(fpr_convention=args.fpr_convention, ap_convention=args.ap_convention)
                   for name, acc in accumulators.items()}
        write_json_atomic(out / "metrics.json", {"metrics": metrics})
        print(results_table(metrics))


if __name__ == "__main__":
    sys.exit(main())
