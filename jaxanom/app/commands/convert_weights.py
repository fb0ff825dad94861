"""``jaxanom convert-weights``: PyTorch weights -> a run folder (DeepLabV3+, ESPNet, ERFNet) or a VGG folder."""
from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from pathlib import Path

from jaxanom.app.outputs import out_folder
from jaxanom.errors import InputError, first_line, reading
from jaxanom.weights import KINDS

__all__ = ["DEEPLAB_CLASSES", "KINDS", "convert_weights"]

DEEPLAB_CLASSES = 19


def convert_weights(*, kind: str, input: str, out: str, num_classes: int | None = None,
                    output_stride: int | None = None, seed: int = 0, overwrite: bool = False) -> Path:
    """Read the checkpoint ``input`` holding ``kind`` (``jaxanom.weights.KINDS``) and write it into
    the new or empty folder ``out``: a run folder that ``evaluate --run`` and ``train --init-from``
    read, or ``vgg.npz`` + ``vgg.json``. ``num_classes`` and ``output_stride`` (default 19 and 8)
    configure a DeepLabV3+; ESPNet and ERFNet take the checkpoint's classes and have no output
    stride to set. Returns ``out``."""
    import jax

    from jaxanom.app.runs import write_run
    from jaxanom.weights import PRESETS, RUN_KINDS, from_torch, read_state_dict, run_preset, write_vgg
    from jaxanom.weights.store import VGG_CONFIG, VGG_FILE

    if output_stride is not None and kind not in PRESETS:  # refused before any folder is made
        raise InputError("output_stride", f": {kind} is no DeepLabV3+ and has no output stride to set; got "
                         f"{output_stride} (leave it out)")
    out_dir = out_folder(out, overwrite)
    held = [name for name in ("experiment.json", "checkpoints") if (out_dir / name).exists()]
    if held and kind in RUN_KINDS:  # a run's checkpoints would outlive the new experiment.json, or hide step 0
        raise InputError("out", f"{out_dir}: holds a run ({', '.join(held)}); {{overwrite}} does not replace runs: "
                         "choose an empty folder, or delete that run first", mentions=("overwrite",))
    if num_classes is not None and kind.startswith("torchvision-vgg"):
        raise InputError("num_classes", f": {kind} is a feature extractor without classes; got {num_classes}")
    classes = DEEPLAB_CLASSES if num_classes is None else num_classes
    with reading("input"):  # a checkpoint that is unreadable, or not of ``kind``
        state = read_state_dict(input)
        model, variables = from_torch(state, kind, classes, key=jax.random.key(seed), output_stride=output_stride or 8)
    if num_classes is not None and model.num_classes != num_classes:  # the checkpoint fixed the count
        raise InputError("num_classes", f": {kind} takes its class count from the checkpoint "
                         f"({model.num_classes}); got {num_classes} (leave it out)")
    preset = run_preset(kind, model)
    if preset is not None:
        with _staged(out_dir) as staging:
            write_run(staging, preset, model, variables)
            os.replace(staging / "checkpoints", out_dir / "checkpoints")  # a folder without experiment.json is no run
            os.replace(staging / "experiment.json", out_dir / "experiment.json")
        print(f"{kind}: {len(state)} tensors -> run folder {out_dir} (model {preset})")
    else:
        with _staged(out_dir) as staging:
            write_vgg(staging, model, variables)
            for name in (VGG_FILE, VGG_CONFIG):
                os.replace(staging / name, out_dir / name)
        print(f"{kind}: {len(state)} tensors -> {out_dir}")
    return out_dir


@contextlib.contextmanager
def _staged(out: Path):
    """A hidden temporary folder in ``out`` (``.convert.*.tmp``: a stale claim's clean-up finds it),
    removed however the block ends; a failure to write there (a full disk) is one line, and the
    writer's background threads log nothing meanwhile."""
    staging = Path(tempfile.mkdtemp(dir=out, prefix=".convert.", suffix=".tmp"))
    loggers = [logging.getLogger(name) for name in ("absl", "asyncio")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield staging
    except Exception as error:
        raise InputError("out", f"{out}: could not write the converted weights ({type(error).__name__}: "
                         f"{first_line(error)}); nothing was left behind") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)
