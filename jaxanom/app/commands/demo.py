"""``jaxanom demo``: one of the demos (SML + CuDAM by default, MMF, off-road) into a new or empty folder.

The one module that imports ``jaxanom.app.demos``: the demos are leaves, run, never built upon.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxanom.app.outputs import out_folder
from jaxanom.errors import InputError, reading

__all__ = ["PAPERS", "demo"]

PAPERS = ("mmf", "offroad")  # the other papers' demos; None: SML + CuDAM


def demo(paper: str | None = None, *, out: str = "jaxanom-demo", quick: bool = False, steps: int | None = None,
         config: str | None = None, synthesizer: str | None = None, overwrite: bool = False,
         progress: bool = True) -> None:
    """Run the demo of ``paper`` (None: SML + CuDAM) into ``out`` (the off-road demo's default
    folder is ``jaxanom-demo-offroad``): ``quick`` a smoke run at tiny sizes, ``steps`` training
    steps, ``config`` a JSON file of the MMF / off-road demo's config, ``synthesizer`` MMF's."""
    if paper == "offroad":
        return _offroad(out, quick, steps, config, overwrite, progress)
    if paper == "mmf":
        return _mmf(out, quick, steps, config, synthesizer, overwrite, progress)
    if paper is not None:
        raise InputError("paper", f": expected one of {PAPERS} or None, got {paper!r}")
    from jaxanom.app.demos.sml_cudam import DemoConfig, run_demo

    settings = DemoConfig.quick() if quick else DemoConfig()
    if steps is not None:
        experiment = settings.experiment
        settings = dataclasses.replace(settings, experiment=dataclasses.replace(
            experiment, train=dataclasses.replace(experiment.train, steps=steps)))
    run_demo(out_folder(out, overwrite), settings, progress=progress)


def _mmf(out, quick, steps, config, synthesizer, overwrite, progress) -> None:
    """``jaxanom demo mmf [--quick | --config FILE] [--steps N] [--out DIR] [--overwrite]`` (N: segmenter steps)."""
    from jaxanom.app.demos.mmf import run_mmf_demo
    from jaxanom.app.mmf_experiment import MMFDemoConfig, load_config

    if quick and config:
        raise InputError("quick", ", {config}: give one of them", mentions=("config",))
    with reading("config"):
        settings = load_config(config) if config else MMFDemoConfig.quick() if quick else MMFDemoConfig()
    if steps is not None:
        seg = settings.pipeline.segmenter
        seg = dataclasses.replace(seg, train=dataclasses.replace(seg.train, steps=steps))
        settings = dataclasses.replace(settings, pipeline=dataclasses.replace(settings.pipeline, segmenter=seg))
    if synthesizer:
        settings = dataclasses.replace(settings, pipeline=dataclasses.replace(settings.pipeline, synthesizer=synthesizer))
    run_mmf_demo(out_folder(out, overwrite), settings, progress=progress)


def _offroad(out, quick, steps, config, overwrite, progress) -> None:
    """``jaxanom demo offroad [--quick] [--steps N] [--config FILE] [--out DIR]``."""
    from jaxanom.app.demos.offroad import run_offroad_demo
    from jaxanom.app.offroad_experiment import OffroadDemoConfig

    if config and quick:
        raise InputError("config", " and {quick}: give one of them", mentions=("quick",))
    if config and not Path(config).is_file():
        raise InputError("config", f"{config}: no such file")
    with reading("config"):
        settings = OffroadDemoConfig.from_json(config) if config else (
            OffroadDemoConfig.quick() if quick else OffroadDemoConfig())
    if steps is not None:
        encoder = dataclasses.replace(settings.pipeline.encoder, steps=steps)
        settings = dataclasses.replace(settings, pipeline=dataclasses.replace(settings.pipeline, encoder=encoder))
    out = "jaxanom-demo-offroad" if out == "jaxanom-demo" else out
    run_offroad_demo(out_folder(out, overwrite), settings, progress=progress)
