"""``jaxanom predict``: anomaly maps of image files with a run's network, resumable (``jaxanom.app.predict``)."""
from __future__ import annotations

import json
from pathlib import Path

from jaxanom.app.commands.inputs import (DEFAULT_METHODS, check_stats_classes, load_plugins, method_names,
                                         method_options, read_stats, split_overrides, with_overrides)
from jaxanom.app.outputs import inside, out_folder, within
from jaxanom.app.predict import FORMATS, SMIYC_DATASETS
from jaxanom.errors import InputError, reading

__all__ = ["FORMATS", "SMIYC_DATASETS", "predict"]


def predict(images, *, run: str, out: str, methods: str | None = None, plugins=(), stats: str | None = None,
            formats: str = "npy", size: tuple[int, int] | None = None, batch_size: int = 1,
            dataset: str | None = None, slic_step: int | None = None, cudam_sigma: float | None = None,
            unit_interval: tuple[float, float] | None = None, threads: int | None = None, overrides=(),
            overwrite: bool = False,
            progress: bool = True) -> dict:
    """Score the image files, folders or glob patterns ``images`` with ``run``'s network into
    ``out`` (comma-separated ``methods`` and ``formats``, see ``jaxanom.app.predict``; then each
    ``"dotted.name=VALUE"`` of ``overrides`` sets a field of the ``PredictSettings``, or with
    ``"methods.METHOD.OPTION=VALUE"`` an option of a method, ``slic_step`` and ``cudam_sigma``
    being the same as ``methods.<m>.slic_step`` / ``methods.cudam.cudam_sigma`` for each method
    declaring it; ``threads``: host threads decoding and writing, None for ``default_threads()``).
    A rerun with the same settings, options, network and statistics skips the frames already
    written; one with others is refused unless ``overwrite`` (which recomputes every frame).
    Returns the summary of ``predict_images``."""
    from jaxanom.app import scoring
    from jaxanom.app.evaluate import predictor
    from jaxanom.app.experiment import build_network, jsonable, load_experiment, load_run_plugins, load_variables
    from jaxanom.app.predict import (DeviceOutOfMemory, PredictSettings, Scorer, check_resumable, fingerprint,
                                     list_images, predict_images, remove_other_maps, settings_record,
                                     size_check)
    from jaxanom.io import write_json_atomic

    load_plugins(plugins)
    with reading("run", run):  # the run's recorded plug-ins first: their methods may be asked for
        load_run_plugins(run)
    settings = PredictSettings(methods=method_names(methods, DEFAULT_METHODS), formats=tuple(formats.split(",")),
                               size=size, batch_size=batch_size, dataset=dataset, unit_interval=unit_interval,
                               threads=threads)
    if slic_step is not None and slic_step < 1:
        raise InputError("slic_step", f": expected >= 1, got {slic_step}")
    option_overrides, overrides = split_overrides(overrides)
    settings = with_overrides(settings, overrides)  # first: --set methods=... picks the methods the options are of
    options = method_options(settings.methods, option_overrides, slic_step=slic_step, cudam_sigma=cudam_sigma)
    if "smiyc" in settings.formats:
        try:
            import h5py  # noqa: F401
        except ImportError:
            raise InputError("formats", " smiyc: needs h5py (pip install 'jaxanom[smiyc]')") from None
    run_dir, out_dir = Path(run), Path(out)
    paths, left_out = list_images(images, out_dir)
    if not (run_dir / "experiment.json").is_file():
        raise InputError("run", f"{run_dir}: expected a run folder (with experiment.json)")
    if inside(out_dir, run_dir):
        raise InputError("out", f"{out_dir}: lies inside {{run}} {run_dir}; predict never writes into a run",
                         mentions=("run",))
    with reading("run", run_dir):
        experiment = load_experiment(run_dir)
    mean_std = read_stats(stats)
    scoring.check(settings.methods, scoring.run_inputs(experiment, stats=mean_std is not None), options)
    model = build_network(experiment)
    with reading("run", run_dir):
        _, variables = load_variables(run_dir)
    check = size_check(model, variables)
    if settings.size is not None:
        check(settings.size, "the working size")
    if mean_std is not None:
        check_stats_classes(mean_std, stats, model, variables, experiment.crop)
    # the maps depend on what the files hold, not where they are: a moved run resumes, a re-fitted one does not
    network = fingerprint({"experiment": json.dumps(jsonable(experiment), sort_keys=True), "variables": variables})
    record = settings_record(settings, network=network,
                             statistics=None if mean_std is None else fingerprint(mean_std),
                             options=options, read_from={"run": str(run_dir.resolve()),
                                        "stats": None if stats is None else str(Path(stats).resolve())})
    resuming = not overwrite and out_dir.is_dir() and check_resumable(out_dir, record)
    out_dir = out_folder(out, overwrite or resuming, hint="pass {overwrite} (or rerun with its settings)")
    if overwrite and (removed := remove_other_maps(out_dir, record, settings)):
        print(f"jaxanom predict: removed {removed} maps of other settings, network or statistics from {out_dir}")
    write_json_atomic(within(out_dir, out_dir / "settings.json"), record)
    scorer = Scorer(predictor(model, variables), settings, mean_std, check_size=None if settings.size else check,
                    options=options)
    try:
        summary = predict_images(paths, out_dir, scorer, progress=progress, redo=overwrite)
    except DeviceOutOfMemory as error:
        raise InputError("batch_size", f"{error}; rerun with a smaller {{batch_size}} to resume, or a smaller {{size}} "
                         "(into another {out}, or with {overwrite})", mentions=("size", "out", "overwrite")) from None
    skipped = f", {left_out} images under --out left out" if left_out else ""
    print(f"jaxanom predict: {summary['written']} frames written, {summary['skipped']} already there{skipped}, "
          f"{len(settings.methods)} methods, formats {','.join(settings.formats)} -> {out_dir}")
    return summary
