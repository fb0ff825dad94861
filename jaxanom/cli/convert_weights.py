"""``jaxanom convert-weights``: PyTorch weights -> a run folder (DeepLabV3+, ESPNet, ERFNet) or a VGG folder."""
from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from pathlib import Path

from jaxanom.cli.common import CommandError, add_common, nonnegative_int, out_folder
from jaxanom.train.checkpoint import _first_line
from jaxanom.weights.store import VGG_CONFIG, VGG_FILE

DEEPLAB_CLASSES = 19


def add_parser(commands) -> None:
    from jaxanom.weights import KINDS

    parser = commands.add_parser(
        "convert-weights", help="import PyTorch weights (torchvision ResNet/VGG, the SML authors' DeepLabV3+, "
        "the ESPNet and ERFNet authors' Cityscapes networks)",
        description="Read a PyTorch checkpoint (.pth/.pt via torch.load(weights_only=True), or .npz / .safetensors "
        "with the same names) and write it for jaxanom. DeepLabV3+ kinds, espnet-cityscapes (p, q and classes "
        "read from the checkpoint) and erfnet-cityscapes (the authors' float checkpoint or its int8 redistribution, "
        "classes read from the checkpoint) give a run folder that `evaluate --run` and `train --init-from` read "
        "(torchvision-resnet*: ImageNet backbone, head initialised from --seed); "
        "VGG kinds give vgg.npz + vgg.json (jaxanom.weights.read_vgg).")
    parser.add_argument("--from", dest="kind", required=True, choices=KINDS, help="what the checkpoint holds")
    parser.add_argument("input", metavar="IN", help="checkpoint file")
    parser.add_argument("out", metavar="OUT", help="output folder (new or empty)")
    parser.add_argument("--num-classes", type=int, default=None, help="classes of the DeepLabV3+ (default: "
                        f"{DEEPLAB_CLASSES}); espnet-cityscapes and erfnet-cityscapes take the checkpoint's, and "
                        "refuse another count")
    parser.add_argument("--output-stride", type=int, choices=[8, 16], default=8,
                        help="DeepLabV3+ output stride (default: %(default)s)")
    parser.add_argument("--seed", type=nonnegative_int, default=0,
                        help="seed of the head of torchvision-resnet* (default: %(default)s)")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    import jax

    from jaxanom.app.runs import write_run
    from jaxanom.weights import RUN_KINDS, from_torch, read_state_dict, run_preset, write_vgg

    out = out_folder(args.out, args.overwrite)
    held = [name for name in ("experiment.json", "checkpoints") if (out / name).exists()]
    if held and args.kind in RUN_KINDS:  # a run's checkpoints would outlive the new experiment.json, or hide step 0
        raise CommandError(f"OUT {out}: holds a run ({', '.join(held)}); --overwrite does not replace runs: "
                           "choose an empty folder, or delete that run first")
    if args.num_classes is not None and args.kind.startswith("torchvision-vgg"):
        raise CommandError(f"--num-classes: {args.kind} is a feature extractor without classes; got {args.num_classes}")
    state = read_state_dict(args.input)
    classes = DEEPLAB_CLASSES if args.num_classes is None else args.num_classes
    model, variables = from_torch(state, args.kind, classes, key=jax.random.key(args.seed),
                                  output_stride=args.output_stride)
    if args.num_classes is not None and model.num_classes != args.num_classes:  # the checkpoint fixed the count
        raise CommandError(f"--num-classes: {args.kind} takes its class count from the checkpoint "
                           f"({model.num_classes}); got {args.num_classes} (leave it out)")
    preset = run_preset(args.kind, model)
    if preset is not None:
        with _staged(out) as staging:
            write_run(staging, preset, model, variables)
            os.replace(staging / "checkpoints", out / "checkpoints")  # a folder without experiment.json is no run
            os.replace(staging / "experiment.json", out / "experiment.json")
        print(f"{args.kind}: {len(state)} tensors -> run folder {out} (model {preset})")
    else:
        with _staged(out) as staging:
            write_vgg(staging, model, variables)
            for name in (VGG_FILE, VGG_CONFIG):
                os.replace(staging / name, out / name)
        print(f"{args.kind}: {len(state)} tensors -> {out}")


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
        raise CommandError(f"{out}: could not write the converted weights ({type(error).__name__}: "
                           f"{_first_line(error)}); nothing was left behind") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)
