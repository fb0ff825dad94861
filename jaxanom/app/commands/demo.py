"""``jaxanom demo``: one of the demos (SML + CuDAM by default, MMF, off-road) into a new or empty folder.

The one module that imports ``jaxanom.app.demos``: the demos are leaves, run, never built upon.
"""
from __future__ import annotations

import dataclasses

from jaxanom.app.commands.inputs import load_plugins, read_config, with_overrides
from jaxanom.app.outputs import out_folder
from jaxanom.errors import InputError, reading

__all__ = ["PAPERS", "demo"]

PAPERS = ("mmf", "offroad")  # the other papers' demos; None: SML + CuDAM


def demo(paper: str | None = None, *, out: str = "jaxanom-demo", quick: bool = False, steps: int | None = None,
         config: str | None = None, synthesizer: str | None = None, plugins=(), overrides=(),
         overwrite: bool = False, progress: bool = True) -> None:
    """Run the demo of ``paper`` (None: SML + CuDAM) into ``out`` (the off-road demo's default
    folder is ``jaxanom-demo-offroad``): ``quick`` a smoke run at tiny sizes, ``steps`` training
    steps, ``config`` a file of the demo's config (``DemoConfig``, ``MMFDemoConfig`` or
    ``OffroadDemoConfig``: JSON, e.g. a results.json of the same demo, or Python defining
    ``config``), ``synthesizer`` MMF's, then each ``"dotted.name=VALUE"`` of ``overrides``; the
    whole config is checked before ``out`` is claimed. ``plugins``: modules imported first (e.g.
    one registering an objective the config names)."""
    load_plugins(plugins)
    if paper == "offroad":
        return _offroad(out, quick, steps, config, overrides, overwrite, progress)
    if paper == "mmf":
        return _mmf(out, quick, steps, config, synthesizer, overrides, overwrite, progress)
    if paper is not None:
        raise InputError("paper", f": expected one of {PAPERS} or None, got {paper!r}")
    from jaxanom.app.demos.sml_cudam import DemoConfig, run_demo

    settings = _settings(DemoConfig, quick, config)
    if steps is not None:
        experiment = settings.experiment
        settings = dataclasses.replace(settings, experiment=dataclasses.replace(
            experiment, train=dataclasses.replace(experiment.train, steps=steps)))
    settings = with_overrides(settings, overrides)
    _check_training(settings.experiment, "experiment")
    run_demo(out_folder(out, overwrite), settings, progress=progress)


def _settings(cls, quick: bool, config: str | None):
    """``config``'s ``cls``, else ``quick``'s or the default one."""
    if quick and config:
        raise InputError("quick", ", {config}: give one of them", mentions=("config",))
    return read_config(config, cls) if config else cls.quick() if quick else cls()


def _check_training(experiment, field: str) -> None:
    """The checks a training run makes when it starts, made before ``out`` is claimed: InputError
    naming the config's ``field`` (the experiment within it) and the field that does not fit."""
    from jaxanom.app.experiment import check_data, check_objective, check_schedule

    with reading(field):
        check_objective(experiment)
        check_schedule(experiment)
        check_data(experiment)


def _mmf(out, quick, steps, config, synthesizer, overrides, overwrite, progress) -> None:
    """``jaxanom demo mmf [--quick | --config FILE] [--steps N] [--set NAME=VALUE] [--out DIR] [--overwrite]``
    (N: segmenter steps)."""
    from jaxanom.app.demos.mmf import run_mmf_demo
    from jaxanom.app.mmf_experiment import MMFDemoConfig

    settings = _settings(MMFDemoConfig, quick, config)
    if steps is not None:
        seg = settings.pipeline.segmenter
        seg = dataclasses.replace(seg, train=dataclasses.replace(seg.train, steps=steps))
        settings = dataclasses.replace(settings, pipeline=dataclasses.replace(settings.pipeline, segmenter=seg))
    if synthesizer:
        settings = dataclasses.replace(settings, pipeline=dataclasses.replace(settings.pipeline, synthesizer=synthesizer))
    settings = with_overrides(settings, overrides)
    _check_training(settings.pipeline.segmenter, "pipeline.segmenter")
    run_mmf_demo(out_folder(out, overwrite), settings, progress=progress)


def _offroad(out, quick, steps, config, overrides, overwrite, progress) -> None:
    """``jaxanom demo offroad [--quick | --config FILE] [--steps N] [--set NAME=VALUE] [--out DIR]``."""
    from jaxanom.app.demos.offroad import run_offroad_demo
    from jaxanom.app.offroad_experiment import OffroadDemoConfig, check_sources

    settings = _settings(OffroadDemoConfig, quick, config)
    if steps is not None:
        encoder = dataclasses.replace(settings.pipeline.encoder, steps=steps)
        settings = dataclasses.replace(settings, pipeline=dataclasses.replace(settings.pipeline, encoder=encoder))
    settings = with_overrides(settings, overrides)
    check_sources(settings)
    out = "jaxanom-demo-offroad" if out == "jaxanom-demo" else out
    run_offroad_demo(out_folder(out, overwrite), settings, progress=progress)
