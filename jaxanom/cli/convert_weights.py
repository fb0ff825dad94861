"""``jaxanom convert-weights``: PyTorch weights -> a run folder (DeepLabV3+, ESPNet) or a VGG folder."""
from __future__ import annotations

from jaxanom.cli.common import add_common, out_folder


def add_parser(commands) -> None:
    from jaxanom.weights import KINDS

    parser = commands.add_parser(
        "convert-weights", help="import PyTorch weights (torchvision ResNet/VGG, the SML authors' DeepLabV3+, "
        "the ESPNet authors' Cityscapes ESPNet)",
        description="Read a PyTorch checkpoint (.pth/.pt via torch.load(weights_only=True), or .npz / .safetensors "
        "with the same names) and write it for jaxanom. DeepLabV3+ kinds and espnet-cityscapes (p, q and classes "
        "read from the checkpoint) give a run folder that `evaluate --run` and `train --init-from` read "
        "(torchvision-resnet*: ImageNet backbone, head initialised from --seed); "
        "VGG kinds give vgg.npz + vgg.json (jaxanom.weights.read_vgg).")
    parser.add_argument("--from", dest="kind", required=True, choices=KINDS, help="what the checkpoint holds")
    parser.add_argument("input", metavar="IN", help="checkpoint file")
    parser.add_argument("out", metavar="OUT", help="output folder (new or empty)")
    parser.add_argument("--num-classes", type=int, default=19, help="classes of the DeepLabV3+ "
                        "(default: %(default)s; espnet-cityscapes takes the checkpoint's)")
    parser.add_argument("--output-stride", type=int, choices=[8, 16], default=8,
                        help="DeepLabV3+ output stride (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the head of torchvision-resnet* (default: %(default)s)")
    add_common(parser, progress=False)
    parser.set_defaults(handler=run)


def run(args) -> None:
    import jax

    from jaxanom.weights import from_torch, read_state_dict, run_preset, write_run, write_vgg

    state = read_state_dict(args.input)
    model, variables = from_torch(state, args.kind, args.num_classes, key=jax.random.key(args.seed),
                                  output_stride=args.output_stride)
    out = out_folder(args.out, args.overwrite)
    preset = run_preset(args.kind, model)
    if preset is not None:
        write_run(out, preset, model, variables)
        print(f"{args.kind}: {len(state)} tensors -> run folder {out} (model {preset})")
    else:
        write_vgg(out, model, variables)
        print(f"{args.kind}: {len(state)} tensors -> {out}")
