"""``jaxanom evaluate``: pooled anomaly metrics on an anomaly dataset, of a run's network, an MMF
pipeline's folder or score maps written by ``jaxanom predict --format smiyc``; or a run's
segmentation mIoU on a segmentation dataset (``SEGMENTATION``: CamVid)."""
from __future__ import annotations

import numpy as np

from jaxanom.app.commands.inputs import (DEFAULT_METHODS, check_stats_classes, evaluator_names, load_plugins,
                                         method_names, method_options, read_stats, split_overrides)
from jaxanom.app.outputs import check_out_outside, out_folder, within
from jaxanom.errors import InputError, reading

__all__ = ["MMF_DEFAULT_METHODS", "SEGMENTATION", "TRACKS", "evaluate", "segmentation", "statistics_record"]

MMF_DEFAULT_METHODS = ("entropy", "resynthesis", "resynthesis_post", "mmf_raw", "mmf")
# SegmentMeIfYouCan's component rules per dataset (smiyc: RoadAnomaly21 or RoadObstacle21, say which)
TRACKS = {"synthetic": "anomaly", "road-anomaly": "anomaly", "fishyscapes-laf": "anomaly",
          "fishyscapes-static": "anomaly", "lost-and-found": "obstacle", "smiyc": None}
# segmentation datasets: name -> (its splits, the default one)
SEGMENTATION = {"camvid": (("train", "val", "test"), "test")}


def evaluate(*, dataset: str, path: str, out: str, run: str | None = None, mmf: str | None = None,
             maps: str | None = None, base: str | None = None, depth: str | None = None, frames: int = 64,
             stats: str | None = None, methods: str | None = None, plugins=(), fpr_convention: str | None = None,
             ap_convention: str = "step", cudam_sigma: float | None = None, track: str | None = None,
             convention: str = "exact", protocol: str = "native", pictures: int = 0,
             all_conventions: bool = False, evaluators: str | None = None, overrides=(), split: str | None = None,
             overwrite: bool = False) -> dict:
    """Score ``dataset`` (its folder ``path``) with one of ``run`` (a network), ``mmf`` (a folder
    of ``jaxanom demo mmf``) or ``maps`` (saved score maps) and write ``out/metrics.json``, which
    is returned; prints the results table. ``track`` picks SegmentMeIfYouCan's component rules
    (default: the dataset's), ``protocol`` how frames become counted pixels (with ``run``; a
    ``jaxanom.protocols`` name, a plug-in's included);
    ``all_conventions`` also prints every AP and FPR convention side by side. ``evaluators``:
    comma-separated names of evaluators (``jaxanom.metrics.evaluator``, a plug-in's included) also
    fed each method's scores, their metrics in ``metrics[method]["evaluators"][name]``. ``overrides``:
    ``"methods.METHOD.OPTION=VALUE"`` options of the methods (``cudam_sigma`` is the same as
    ``"methods.cudam.cudam_sigma=..."``); ``metrics[name]["options"]`` records each option's values
    as resolved."""
    from jaxanom._validate import check_number
    from jaxanom.app import scoring
    from jaxanom.app.evaluate import anomaly_results, dataset_reader, predictor, protocol_predictions, saved_map_batches
    from jaxanom.app.experiment import build_network, load_experiment, load_variables
    from jaxanom.app.mmf_experiment import mmf_scored_batches
    from jaxanom.app.predict import size_check
    from jaxanom.app.reports import conventions_table, evaluators_lines, results_table
    from jaxanom.io import write_json_atomic
    from jaxanom.protocols import get_protocol

    if sum(x is not None for x in (run, mmf, maps)) != 1:
        raise InputError("run", ", {mmf}, {maps}: give exactly one", mentions=("mmf", "maps"))
    if dataset not in TRACKS and dataset not in SEGMENTATION:
        raise InputError("dataset", f": expected one of {', '.join([*TRACKS, *SEGMENTATION])}, got {dataset!r}")
    if dataset in SEGMENTATION:
        given = {"mmf": mmf, "maps": maps, "stats": stats, "methods": methods, "track": track,
                 "cudam_sigma": cudam_sigma, "base": base, "depth": depth, "pictures": pictures or None,
                 "protocol": None if protocol == "native" else protocol, "overrides": list(overrides) or None,
                 "evaluators": evaluators}
        refused = [name for name, value in given.items() if value is not None]
        if refused:
            raise InputError(refused[0], f": scores anomalies; the {dataset} dataset is scored for segmentation "
                             "(mIoU) only, from {run}", mentions=("run",))
        return segmentation(run=run, dataset=dataset, path=path, split=split, out=out, overwrite=overwrite)
    if split is not None:
        raise InputError("split", f": picks the frames of a segmentation dataset ({', '.join(SEGMENTATION)}); "
                         f"{dataset} has none")
    track = track or TRACKS[dataset]
    if track is None:
        raise InputError("track", ": the smiyc dataset holds either track; pass {track} anomaly (RoadAnomaly21) or "
                         "{track} obstacle (RoadObstacle21)")
    check_out_outside(out, {"run": run, "mmf": mmf, "maps": maps})
    load_plugins(plugins)  # before the protocol, methods and evaluators are looked up: a plug-in may name any
    protocol_ = get_protocol(protocol)
    extra = evaluator_names(evaluators)
    if protocol_.name != "native" and not run:
        raise InputError("protocol", f" {protocol_.name}: resizes the frames the network sees, so it needs {{run}}",
                         mentions=("run",))
    if maps and stats:  # the maps are finished scores: statistics would change nothing, silently
        raise InputError("stats", f" {stats}: {{maps}} reads finished score maps, which no statistics change; "
                         "leave it out", mentions=("maps",))
    if maps and overrides:  # nor would the methods' options
        raise InputError("overrides", f" {overrides[0]}: {{maps}} reads finished score maps, which no method option "
                         "changes; leave it out", mentions=("maps",))
    mean_std = read_stats(stats)
    if cudam_sigma is not None:
        check_number("cudam_sigma", cudam_sigma, 0.0, open_low=True)

    if others := split_overrides(overrides)[1]:
        raise InputError("overrides", f" {others[0]}: evaluate sets options of the methods only: "
                         "methods.METHOD.OPTION=VALUE")

    def options_of(names) -> dict:
        return method_options(names, overrides, cudam_sigma=cudam_sigma)

    options: dict = {}
    if mmf:  # every check before the first frame is read or scored
        names = scoring.check(method_names(methods, MMF_DEFAULT_METHODS),
                              scoring.provided(classes=None, stats=mean_std is not None, mmf_maps=True))
        options = options_of(names)
        source, batches = mmf_scored_batches(mmf, dataset, path, frames=frames, depth=depth)
    elif maps:
        with reading("path", path):  # a folder that does not hold the dataset
            source = dataset_reader(dataset, path, base=base, frames=frames, depth=depth)
        try:
            names, batches = saved_map_batches(maps, source, method_names(methods, ()) or None, track)
        except FileNotFoundError as error:
            raise InputError("maps", f": {error}") from None
    else:  # the frames' images come with every batch (evaluation_batches)
        with reading("run", run):
            experiment = load_experiment(run)
        names = scoring.check(method_names(methods, DEFAULT_METHODS),
                              scoring.run_inputs(experiment, stats=mean_std is not None))
        options = options_of(names)
        with reading("path", path):  # a folder that does not hold the dataset
            source = dataset_reader(dataset, path, base=base, frames=frames, depth=depth)
        with reading("run", run):
            experiment, variables = load_variables(run)
        network = build_network(experiment)
        if mean_std is not None:  # refused before the first frame is scored
            check_stats_classes(mean_std, stats, network, variables, experiment.crop, protocol_)
        predict = predictor(network, variables)
    skipped: list[str] = []
    if run:
        batches = protocol_predictions(predict, source, protocol_, skipped,
                                       check_size=size_check(network, variables, "path", advice=""))
    out_dir = out_folder(out, overwrite)
    try:
        metrics, _ = anomaly_results(batches, names, stats=mean_std, options=options,
                                     fpr_convention=fpr_convention or protocol_.fpr_convention,
                                     ap_convention=ap_convention, track=None if track == "none" else track,
                                     spill_dir=out_dir, convention=convention, drop_void=protocol_.drop_void,
                                     evaluators=extra)
    except InputError as error:  # no frame, or no class, left to score: say which frames the protocol skipped
        if error.argument != "path" or not skipped:
            raise
        raise InputError("path", f"{error.message.rstrip('.')}; the {protocol_.name} protocol skipped "
                         f"{len(skipped)} frames without anomaly pixels ({', '.join(skipped[:5])}"
                         f"{', ...' if len(skipped) > 5 else ''})") from None
    if skipped:
        print(f"jaxanom evaluate: the {protocol_.name} protocol skipped {len(skipped)} of {len(source)} frames, "
              f"which have no anomaly pixel: {', '.join(skipped[:10])}{', ...' if len(skipped) > 10 else ''} "
              "(metrics.json: frames_skipped)")
    record = {"dataset": dataset, "path": path, "frames": len(source), "convention": convention,
              "protocol": protocol_.name, "metrics": metrics}
    if skipped:
        record["frames_skipped"] = skipped
    if mmf:
        record["mmf"] = mmf
    if maps:
        record["maps"] = maps
    if mean_std is not None:
        record["sml_statistics"] = statistics_record(stats)
    for name, method_metrics in metrics.items():  # each option the methods resolved, and whether it was given
        for option, values in method_metrics.get("options", {}).items():
            given = options.get(name, {}).get(option) is not None
            record[option] = {"values": values, "source": "given" if given else "default"}
    write_json_atomic(within(out_dir, out_dir / "metrics.json"), record)
    if pictures and run:  # MMF's pictures: jaxanom demo mmf; maps': jaxanom predict --format png
        from jaxanom.app.reports import write_pictures

        # the frames and logits as the protocol scores them (the statistics describe those logits)
        write_pictures(out_dir, protocol_.outputs(predict), protocol_.source(source), mean_std, pictures,
                       experiment.data)
    if convention == "smiyc":
        print("The official SegmentMeIfYouCan kit's numbers (binned; the exact ones, AP "
              f"{ap_convention} and FPR@95 {fpr_convention or protocol_.fpr_convention}: metrics.json, \"exact\"):")
    print(results_table(metrics))
    if extra:
        print(evaluators_lines(metrics))
    if all_conventions:
        print("\n" + conventions_table(metrics))
    return record


def segmentation(*, run: str | None, dataset: str, path: str, split: str | None, out: str,
                 overwrite: bool = False) -> dict:
    """mIoU over the dataset's classes (its void label ignored), pixel accuracy and per-class IoU of
    ``run``'s network (the argmax of its logits, each frame at its own size) on the frames of
    ``split``; writes ``out/metrics.json``, which is returned, and prints them."""
    from jaxanom.app.evaluate import predictions, predictor, segmentation_results
    from jaxanom.app.experiment import build_network, load_variables
    from jaxanom.app.predict import size_check
    from jaxanom.data.pipeline import evaluation_batches
    from jaxanom.data import CamVid, camvid
    from jaxanom.io import write_json_atomic

    reader, num_classes, names = {"camvid": (CamVid, camvid.NUM_CLASSES, camvid.CLASS_NAMES)}[dataset]
    splits, default = SEGMENTATION[dataset]
    split = split or default
    if split not in splits:
        raise InputError("split", f": expected one of {', '.join(splits)}, got {split!r}")
    if run is None:
        raise InputError("run", f": the {dataset} dataset is scored for segmentation, which needs a network")
    check_out_outside(out, {"run": run})
    with reading("path", path):
        source = reader(path, split)
    with reading("run", run):
        experiment, variables = load_variables(run)
    if experiment.num_classes != num_classes:
        raise InputError("run", f" {run}: has {experiment.num_classes} outputs, expected a network of {dataset}'s "
                         f"{num_classes} classes")
    network = build_network(experiment)
    check = size_check(network, variables, "path", advice="")
    predict = predictor(network, variables)

    def batches():
        for batch in evaluation_batches(source, batch_size=1):
            check(batch["image"].shape[1:3], str(batch["name"][0]))
            yield batch

    scores = segmentation_results(predictions(predict, batches()), num_classes)
    metrics = {"miou": scores["miou"], "pixel_accuracy": scores["pixel_accuracy"], "classes": list(names),
               # None: a class neither labelled nor predicted
               "iou": [None if np.isnan(v) else v for v in scores["per_class_iou"]]}
    record = {"dataset": dataset, "path": path, "split": split, "frames": len(source), "run": run,
              "ignored": "void", "metrics": metrics}
    out_dir = out_folder(out, overwrite)
    write_json_atomic(within(out_dir, out_dir / "metrics.json"), record, allow_nan=False)
    width = max(map(len, names))
    print(f"{dataset} {split}, {len(source)} frames: mIoU {100 * scores['miou']:.2f}%, "
          f"pixel accuracy {100 * scores['pixel_accuracy']:.2f}%")
    for name, value in zip(names, metrics["iou"]):
        print(f"  {name:<{width}}  {'-' if value is None else f'{100 * value:.2f}'}")
    return record


def statistics_record(path: str) -> dict:
    """What ``metrics.json`` says about the SML statistics: file, the frames they were fitted on (or
    "not recorded"), policy, the outputs they describe, counts, pooled and shrunk classes."""
    from jaxanom.sml import load_stats, load_stats_info

    info = load_stats_info(path)
    record = {"file": path, "frames": info["frames"] or "not recorded", "policy": info["policy"],
              "channels": info["channels"],
              "counts": load_stats(path)[2].tolist()}
    if info["status"] is None:
        record["classes"] = "unknown: the file has no per-class status (written without a policy)"
    else:
        record["classes"] = {s: [c for c, x in enumerate(info["status"]) if x == s] for s in ("pooled", "shrunk")}
    return record
