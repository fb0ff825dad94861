"""``jaxanom score``: scores and metrics from logits saved by another framework.

Streams: the logits (and labels) are read one image at a time (``jaxanom.app.streamed_array``),
each image is scored, fed to one exact ``PixelAnomaly`` evaluator per method
(``jaxanom.metrics.evaluator``), and its score maps are appended to ``scores/<method>.npy`` files
that appear only once complete. Memory: one image's logits and
scores, plus the accumulators' ~6 bytes per distinct score (see ``jaxanom.metrics.accumulator``).
"""
from __future__ import annotations

import contextlib

from jaxanom.app.commands.inputs import (DEFAULT_METHODS, evaluator_names, load_plugins, method_names,
                                         method_options, read_stats, split_overrides)
from jaxanom.app.outputs import out_folder, within
from jaxanom.app.streamed_array import StreamedArray
from jaxanom.errors import InputError
from jaxanom.metrics.anomaly import AP_CONVENTIONS

__all__ = ["AP_CONVENTIONS", "score"]


def score(*, logits: str, out: str, layout: str = "NCHW", any_layout: bool = False, labels: str | None = None,
          stats: str | None = None, methods: str | None = None, plugins=(), fpr_convention: str | None = None,
          ap_convention: str = "step", evaluators: str | None = None, overrides=(),
          overwrite: bool = False) -> dict | None:
    """Score the logits file ``logits`` ((N, C, H, W) or, ``layout="NHWC"``, (N, H, W, C)) with
    the comma-separated ``methods`` into ``out/scores/<method>.npy``; with ``labels`` (N, H, W)
    also the metrics (``out/metrics.json``, returned, with each method's options as used).
    ``evaluators``: comma-separated names of evaluators (``jaxanom.metrics.evaluator``, a
    plug-in's included; with ``labels``) also fed every image of each method's scores, their
    metrics in ``metrics[method]["evaluators"][name]``.
    ``overrides``: ``"methods.METHOD.OPTION=VALUE"`` options of the methods."""
    import numpy as np

    from jaxanom.app import scoring
    from jaxanom.app.reports import evaluators_lines, results_table
    from jaxanom.io import NpyWriter, jsonable, write_json_atomic
    from jaxanom.method_registry import check_finite
    from jaxanom.metrics.evaluator import PixelAnomaly, get_evaluator, run_evaluators

    load_plugins(plugins)
    extra = evaluator_names(evaluators)
    if extra and labels is None:
        raise InputError("evaluators", ": the evaluators compare scores with labels; give {labels}",
                         mentions=("labels",))
    streamed = StreamedArray(logits, "logits")
    if streamed.ndim != 4:
        raise InputError("logits", f": expected 4 dimensions ({layout}), got shape {streamed.shape}")
    channels_first = layout == "NCHW"
    size = (streamed.shape[2:] if channels_first else streamed.shape[1:3])
    classes = streamed.shape[1] if channels_first else streamed.shape[3]
    if classes > min(size) and not any_layout:
        raise InputError("logits", f": with {{layout}} {layout}, shape {streamed.shape} has {classes} classes but "
                         f"images of {size[0]} x {size[1]} pixels; check {{layout}}, or pass {{any_layout}} if so",
                         mentions=("layout", "any_layout"))
    label_array = None if labels is None else StreamedArray(labels, "labels")
    shape = (len(streamed), *size)
    if label_array is not None and label_array.shape != shape:
        raise InputError("labels", f": expected shape {shape} (N, H, W) to match the logits, got {label_array.shape}")
    if label_array is not None:  # one pass over the (1 byte a pixel) labels before any work
        pooled = np.sum([((label == 1).sum(), (label == 0).sum()) for label in label_array], axis=0)
        if not pooled.all():
            raise InputError("labels", f" {labels}: no {'anomaly (1)' if not pooled[0] else 'normal (0)'} pixel "
                             f"outside void (255) in any of its {len(label_array)} images; AP, AUROC and FPR@95 "
                             "need both classes (leave {labels} out for the score maps alone)")
    mean_std = read_stats(stats)
    if mean_std is not None and len(mean_std[0]) != classes:
        raise InputError("stats", f": has {len(mean_std[0])} classes, the logits have {classes}")
    names = scoring.check(method_names(methods, DEFAULT_METHODS),
                          scoring.provided(classes=classes, stats=mean_std is not None))
    if others := split_overrides(overrides)[1]:
        raise InputError("overrides", f" {others[0]}: score sets options of the methods only: "
                         "methods.METHOD.OPTION=VALUE")
    options = method_options(names, overrides)
    out_dir = out_folder(out, overwrite)
    used: dict = {}  # the options each method used (resolved for the images' one size)
    current = [None]  # the index of the image being scored (None once all are), named when a value is refused

    def scored():
        """Each image's scores (appended to ``scores/<method>.npy``) with its label, in order."""
        label_images = iter(label_array if label_array is not None else ())
        with contextlib.ExitStack() as files:
            writers = {name: files.enter_context(NpyWriter(within(out_dir, out_dir / "scores" / f"{name}.npy"),
                                                           shape, np.float32)) for name in names}
            for index, image in enumerate(streamed):
                current[0] = index
                image = np.moveaxis(image, 0, -1) if channels_first else image
                label = None if label_array is None else next(label_images)
                scores, options_used = scoring.score_all(names, scoring.inputs_of({"logits": image[None]}, mean_std),
                                                         options)
                scores = {name: np.asarray(value)[0] for name, value in scores.items()}
                for name, value in scores.items():
                    check_finite(name, value, label, where=f" of image {index}")
                yield {"scores": {name: value[None] for name, value in scores.items()},  # a batch of one
                       "label": None if label is None else label[None]}  # the evaluators check the labels
                used.update(options_used)
                for name, value in scores.items():
                    writers[name].write(value)
        current[0] = None
        print(f"score maps of {len(streamed)} images -> {out_dir / 'scores'}/<method>.npy")

    evaluators = {} if label_array is None else {
        name: PixelAnomaly(name, fpr_convention=fpr_convention or "first", ap_convention=ap_convention)
        for name in names}
    evaluators.update({(name, kind): get_evaluator(kind).make(name) for name in names for kind in extra})
    try:
        with contextlib.closing(scored()) as images:  # closed on an error: no partial scores/<method>.npy
            metrics = run_evaluators(evaluators, images)
    except InputError:  # a method's output refused, naming it
        raise
    except ValueError as error:  # the library's checks of one image's values (finite logits, labels)
        if current[0] is None:
            raise
        raise InputError("image", f"{current[0]}: {error}") from None
    if label_array is None:
        return None
    for name in names:
        if used.get(name):
            metrics[name]["options"] = used[name]
    named = [key for key in metrics if isinstance(key, tuple)]
    for name, kind in named:
        metrics[name].setdefault("evaluators", {})[kind] = jsonable(metrics.pop((name, kind)))
    write_json_atomic(within(out_dir, out_dir / "metrics.json"), {"metrics": metrics})
    print(results_table(metrics))
    if named:
        print(evaluators_lines(metrics))
    return metrics

