"""``jaxanom convert-weights``: PyTorch weights -> a run folder (DeepLabV3+, ESPNet, ERFNet) or a VGG folder."""
from __future__ import annotations

from jaxanom.cli.common import add_common, nonnegative_int


def add_parser(commands) -> None:
    from jaxanom.app.commands.convert_weights import DEEPLAB_CLASSES, KINDS

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
    parser.add_argument("--output-stride", type=int, choices=[8, 16],
                        help="DeepLabV3+ output stride (default: 8); the other kinds refuse it")
    parser.add_argument("--seed", type=nonnegative_int, default=0,
                        help="seed of the head of torchvision-resnet* (default: %(default)s)")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    from jaxanom.app.commands.convert_weights import convert_weights

    convert_weights(kind=args.kind, input=args.input, out=args.out, num_classes=args.num_classes,
                    output_stride=args.output_stride, seed=args.seed, overwrite=args.overwrite)
