"""Training on real frames within 2 CPU cores: the Cityscapes ERFNet's encoder frozen, its features
cached once per frame, the decoder (with a new 11-class head) trained on CamVid on top of them.

    python -m experiments.real_training_common --seed 0 [--steps 3000]   # one baseline network

A whole-network ERFNet train step (batch 4, 352x480) costs about 5 s on these cores; with the
encoder frozen, a frame's encoder pass is paid once (``cache_features``) and a step runs the decoder
only. What this regime cannot do: random scaling (the features of a rescaled frame are not a
resampling of the cached ones) and colour jitter; it keeps horizontal flips (each training frame's
flip is cached too) and random crops of the 1/8 feature grid (labels cropped at 8x the offsets):
the decoder sees every crop with the context the encoder had on the whole frame.

* ``cache_features(split, flip)``: the encoder's (h, w, 128) float32 output of each frame of a CamVid
  split at its native 360x480, and its labels, under ``CACHE / <key>`` where the key hashes the
  weight file's bytes, the split's frame names, the size, the flip and ``CACHE_VERSION``; one .npy
  per frame written atomically, so an interrupted caching resumes where it stopped.
* ``train_decoder(settings)``: the decoder (``ERFNetDecoder``, its Cityscapes weights but the new
  head ``decoder/output_conv``, from the seed) trained by jaxanom's ``train_step`` with optax's SGD
  (``make_optimizer``), ``CrossEntropy`` with ENet's class weights; checkpoints every
  ``SAVE_EVERY`` steps (a rerun resumes); at the end the whole ERFNet (frozen encoder + trained
  decoder) is written as a run folder (``runs.write_run``) under ``CACHE / runs / <settings hash>``,
  which ``jaxanom evaluate`` / ``fit-stats`` / ``predict`` read; a finished run is skipped.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

from experiments.real_common import require_realdata

CACHE = Path(os.environ.get("JAXANOM_TRAINING_CACHE", Path.home() / ".cache" / "jaxanom" / "real_training"))
CAMVID = Path(os.environ.get("JAXANOM_CAMVID", "/work/data/CamVid"))
WEIGHTS = ("erfnet", "erfnet_cityscapes_int8.pth")
CACHE_VERSION = 1  # bump when what a cached feature means changes
FEATURES = 128  # channels of the encoder's output, at 1/8 of the frame
STRIDE = 8
SAVE_EVERY = 250


def file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(functools.partial(f.read, 1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def settings_key(values: dict) -> str:
    """16 hex digits of the sha256 of ``values`` as sorted JSON."""
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:16]


@functools.cache
def cityscapes_erfnet() -> tuple[object, dict, str]:
    """``(model, variables, sha256 of the weight file)``: the authors' Cityscapes ERFNet (20 outputs)."""
    from jaxanom.weights import from_torch, read_state_dict

    path = require_realdata(*WEIGHTS)
    model, variables = from_torch(read_state_dict(path), "erfnet-cityscapes")
    return model, variables, file_digest(path)


def encoder_variables() -> dict:
    """The frozen encoder's ``{"params", "batch_stats"}`` (ERFNet's ``encoder`` module)."""
    _, variables, _ = cityscapes_erfnet()
    return {collection: {"encoder": tree["encoder"]} for collection, tree in variables.items()}


def encoder_module(with_taps: bool = False):
    """A module ``(images (B, H, W, 3) in [0, 1], train) -> (B, H/8, W/8, 128)`` whose variables sit
    under ``encoder`` (as in ``ERFNet``); ``with_taps``: ``(features, {"low", "mid"})``, the encoder's
    earlier maps that attention modules read (``jaxanom.models.erfnet``)."""
    import flax.linen as nn

    from jaxanom.models.erfnet import ERFNetEncoder

    class Encoder(nn.Module):
        @nn.compact
        def __call__(self, images, train: bool = False):
            features, taps = ERFNetEncoder(name="encoder")(images, train)
            return (features, taps) if with_taps else features

    return Encoder()


def decoder_module(num_classes: int, attention: str | None = None):
    """A module ``(features (B, h, w, 128), train, low?, mid?) -> {"logits" (B, 8h, 8w, num_classes),
    the attention module's outputs}`` whose variables sit under ``decoder`` and the module's name (as
    in ``ERFNet``), so the trainer's ``train_step`` runs it. ``attention``: a registered attention
    module at ERFNet's ``deep`` position (the encoder's output), reading the taps ``low`` and ``mid``
    (the trainer passes them from the batch: ``extra_inputs``)."""
    import flax.linen as nn
    import jax.numpy as jnp

    from jaxanom.models.attention import get
    from jaxanom.models.erfnet import ERFNetDecoder

    class Decoder(nn.Module):
        extra_inputs = ("low", "mid") if attention is not None else ()

        @nn.compact
        def __call__(self, features, train: bool = False, low=None, mid=None):
            out = {}
            if attention is not None:
                spec = get(attention)
                module = spec.build(dtype=jnp.float32, name=spec.name, **spec.options)
                features, out = spec.attend(module, features, {"low": low, "mid": mid})
            return {**out, "logits": ERFNetDecoder(num_classes, name="decoder")(features, train)}

    return Decoder()


def camvid(split: str):
    from jaxanom.data import CamVid

    return CamVid(CAMVID, split)


def cache_folder(split: str, flip: bool) -> Path:
    """``CACHE / features-<key>`` of a split's frames (one flip state) at their native size."""
    _, _, weights = cityscapes_erfnet()
    frames = camvid(split)
    names = [name for name, _, _ in frames.frames]
    key = settings_key({"weights": weights, "frames": names, "size": [360, 480], "flip": flip,
                        "version": CACHE_VERSION})
    return CACHE / f"features-{split}{'-flip' if flip else ''}-{key}"


def cache_features(split: str, flip: bool = False, log=print) -> tuple[np.ndarray, np.ndarray, float]:
    """``(features (N, 45, 60, 128) float32, labels (N, 360, 480) uint8, seconds per computed frame)``
    of a CamVid split (each frame mirrored left-right when ``flip``), computed where not cached."""
    import jax

    from jaxanom.models.erfnet import normalize_erfnet

    folder = cache_folder(split, flip)
    folder.mkdir(parents=True, exist_ok=True)
    frames = camvid(split)
    forward = None
    computed, seconds = 0, 0.0
    features, labels = [], []
    for i in range(len(frames)):
        path = folder / f"{i:04d}.npz"
        if not path.exists():
            frame = frames[i]
            image, label = frame["image"], frame["label"]
            if flip:
                image, label = image[:, ::-1], label[:, ::-1]
            if forward is None:  # built only where a frame is missing
                encoder, variables = encoder_module(), encoder_variables()
                forward = jax.jit(lambda v, x: encoder.apply(v, normalize_erfnet(x), train=False))
            start = time.perf_counter()
            value = np.asarray(forward(variables, np.ascontiguousarray(image)[None])[0], np.float32)
            seconds += time.perf_counter() - start if computed else 0.0  # the first one compiles
            computed += 1
            partial = folder / f"{i:04d}.partial.npz"
            np.savez(partial, features=value, label=np.ascontiguousarray(label))
            os.replace(partial, path)
            if computed % 25 == 0:
                log(f"  cached {split}{' flipped' if flip else ''} {i + 1}/{len(frames)} "
                    f"({seconds / max(computed - 1, 1):.2f} s/frame)")
        with np.load(path) as stored:
            features.append(stored["features"])
            labels.append(stored["label"])
    per_frame = seconds / (computed - 1) if computed > 1 else float("nan")
    if computed > 1 and not (folder / "timing.json").exists():  # the cost of the session that cached most
        (folder / "timing.json").write_text(json.dumps({"seconds_per_frame": per_frame, "frames_timed": computed - 1}))
    return np.stack(features), np.stack(labels), per_frame


def cache_taps(split: str, flip: bool = False, log=print) -> dict[str, np.ndarray]:
    """``{"low": (N, 90, 120, 64), "mid": (N, 45, 60, 128)}`` float32: the encoder's taps of each frame
    of a CamVid split (as ``cache_features``, beside it under ``taps-...``), computed where not cached."""
    import jax

    from jaxanom.models.erfnet import normalize_erfnet

    folder = CACHE / cache_folder(split, flip).name.replace("features-", "taps-", 1)
    folder.mkdir(parents=True, exist_ok=True)
    frames = camvid(split)
    forward = None
    taps = {"low": [], "mid": []}
    for i in range(len(frames)):
        path = folder / f"{i:04d}.npz"
        if not path.exists():
            image = frames[i]["image"][:, ::-1] if flip else frames[i]["image"]
            if forward is None:
                encoder, variables = encoder_module(with_taps=True), encoder_variables()
                forward = jax.jit(lambda v, x: encoder.apply(v, normalize_erfnet(x), train=False)[1])
            value = forward(variables, np.ascontiguousarray(image)[None])
            partial = folder / f"{i:04d}.partial.npz"
            np.savez(partial, **{k: np.asarray(value[k][0], np.float32) for k in taps})
            os.replace(partial, path)
            if (i + 1) % 50 == 0:
                log(f"  cached taps of {split}{' flipped' if flip else ''} {i + 1}/{len(frames)}")
        with np.load(path) as stored:
            for k in taps:
                taps[k].append(stored[k])
    return {k: np.stack(v) for k, v in taps.items()}


def enet_class_weights(labels: np.ndarray, num_classes: int, c: float = 1.02) -> tuple[float, ...]:
    """ENet's class weights ``1 / ln(c + p_k)``, p_k the share of class k among the valid pixels
    (Paszke et al. 2016, Sec. 5.2; ERFNet's authors weight Cityscapes the same way)."""
    counts = np.bincount(labels[labels != 255].ravel(), minlength=num_classes)[:num_classes]
    return tuple(float(w) for w in 1.0 / np.log(c + counts / counts.sum()))


@dataclasses.dataclass(frozen=True)
class Settings:
    """One decoder training: what its run folder's key hashes."""

    seed: int = 0
    steps: int = 1000
    batch_size: int = 8
    crop: tuple[int, int] = (24, 32)  # on the 1/8 feature grid: 192x256 pixels
    optimizer: str = "adamw"  # the ERFNet authors' Adam, lr 5e-4, weight decay 1e-4, poly decay
    lr: float = 5e-4
    weight_decay: float = 1e-4
    class_weights: str = "enet"  # or "none"
    num_classes: int = 11
    attention: str | None = None  # a registered attention module at the encoder's output
    objective: tuple[tuple[str, float], ...] = ()  # options of the attention module's objective

    def __post_init__(self):
        object.__setattr__(self, "crop", tuple(self.crop))
        object.__setattr__(self, "objective", tuple(sorted((k, v) for k, v in self.objective)))


# fields added after the first networks were trained: left out of the key at their defaults, so
# those networks keep their folders
LATER_FIELDS = {"attention": None, "objective": ()}


def run_folder(settings: Settings) -> Path:
    _, _, weights = cityscapes_erfnet()
    train_key = cache_folder("train", False).name
    fields = {k: v for k, v in dataclasses.asdict(settings).items() if k not in LATER_FIELDS or v != LATER_FIELDS[k]}
    key = settings_key({**fields, "weights": weights, "train": train_key, "version": CACHE_VERSION})
    return CACHE / "runs" / f"decoder-{key}"


def initial_decoder(settings: Settings, example: dict) -> dict:
    """The decoder's variables: the Cityscapes ones, but the new head and the attention module
    (where there is one) fresh from ``settings.seed``. ``example``: a batch (``crops``)."""
    import jax

    from jaxanom.app.experiment import class_layers
    from jaxanom.weights import take_modules

    _, cityscapes, _ = cityscapes_erfnet()
    source = {collection: {"decoder": tree["decoder"]} for collection, tree in cityscapes.items()}
    model = decoder_module(settings.num_classes, settings.attention)
    extras = {name: example[name] for name in model.extra_inputs}
    fresh = jax.device_get(model.init(jax.random.key(settings.seed), example["image"], **extras))
    return take_modules(fresh, source, ("decoder",), keep=class_layers(fresh, source))


def crops(features: np.ndarray, labels: np.ndarray, settings: Settings, step: int,
          taps: dict[str, np.ndarray] | None = None) -> dict:
    """The batch of ``step``: random frames and random crops of the feature grid (labels at 8x the
    offsets; each tap of ``taps`` at the offsets times its size over the grid's), drawn from
    ``(seed, step)`` so a resumed run sees the batches it would have seen."""
    rng = np.random.default_rng([settings.seed, step])
    (h, w), (ch, cw) = features.shape[1:3], settings.crop
    index = rng.choice(len(features), settings.batch_size, replace=False)
    ys, xs = rng.integers(0, h - ch + 1, settings.batch_size), rng.integers(0, w - cw + 1, settings.batch_size)

    def cut(array: np.ndarray, factor: int) -> np.ndarray:
        return np.stack([array[i, factor * y:factor * (y + ch), factor * x:factor * (x + cw)]
                         for i, y, x in zip(index, ys, xs)])

    batch = {"image": cut(features, 1), "label": cut(labels, STRIDE).astype(np.int32)}
    for name, tap in (taps or {}).items():
        batch[name] = cut(tap, tap.shape[1] // h)
    return batch


def decoder_outputs(variables: dict, settings: Settings, features: np.ndarray,
                    taps: dict[str, np.ndarray] | None = None, batch: int = 4):
    """The decoder's outputs (``{"logits", the attention module's}``, inference mode) on whole cached
    frames, ``batch`` at a time."""
    import jax

    model = decoder_module(settings.num_classes, settings.attention)
    forward = jax.jit(lambda v, x, extras: model.apply(v, x, train=False, **extras))
    for i in range(0, len(features), batch):
        yield forward(variables, features[i:i + batch], {k: v[i:i + batch] for k, v in (taps or {}).items()})


def decoder_miou(variables: dict, settings: Settings, features: np.ndarray, labels: np.ndarray,
                 taps: dict[str, np.ndarray] | None = None, batch: int = 4) -> dict:
    """mIoU etc. (``Segmentation`` evaluator) of the decoder on whole cached frames."""
    from jaxanom.metrics.evaluator import Segmentation, run_evaluators

    outputs = decoder_outputs(variables, settings, features, taps, batch)
    batches = ({"logits": out["logits"], "label": labels[i:i + batch]} for i, out in zip(range(0, len(features), batch),
                                                                                        outputs))
    return run_evaluators({"s": Segmentation(settings.num_classes)}, batches)["s"]


def objective_of(settings: Settings, weights):
    """The training objective: cross-entropy, or the attention module's paper objective (its
    registered ``objective``) with ``settings.objective``'s options; ENet's class weights either way."""
    from jaxanom.losses import CrossEntropy
    from jaxanom.models.attention import get
    from jaxanom.objectives import Objective

    if settings.attention is None:
        return CrossEntropy(weights)
    return Objective.class_named(get(settings.attention).objective)(class_weights=weights, **dict(settings.objective))


def train_decoder(settings: Settings, log=print) -> Path:
    """Train (or resume, or skip when finished) one decoder; returns its run folder (the whole ERFNet)."""
    import jax

    from jaxanom.app.runs import write_run
    from jaxanom.models.erfnet import ERFNet
    from jaxanom.train.checkpoint import Checkpointer
    from jaxanom.train.optim import OptimConfig, make_optimizer
    from jaxanom.train.state import TrainState
    from jaxanom.train.step import train_step

    folder = run_folder(settings)
    if (folder / "result.json").exists():
        log(f"{folder}: finished, skipped")
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "settings.json").write_text(json.dumps(dataclasses.asdict(settings), indent=1))
    flips = (False, True)
    train = [cache_features("train", flip, log) for flip in flips]
    features = np.concatenate([train[0][0], train[1][0]])
    labels = np.concatenate([train[0][1], train[1][1]])
    val_features, val_labels, _ = cache_features("val", False, log)
    taps = val_taps = None
    if settings.attention is not None:
        both = [cache_taps("train", flip, log) for flip in flips]
        taps = {k: np.concatenate([both[0][k], both[1][k]]) for k in both[0]}
        del both
        val_taps = cache_taps("val", False, log)
    weights = enet_class_weights(labels, settings.num_classes) if settings.class_weights == "enet" else None
    model = decoder_module(settings.num_classes, settings.attention)
    objective = objective_of(settings, weights)
    tx, _ = make_optimizer(OptimConfig(settings.optimizer, lr=settings.lr, weight_decay=settings.weight_decay),
                           settings.steps)
    state = TrainState.create(initial_decoder(settings, crops(features, labels, settings, 0, taps)), tx,
                              jax.random.key(settings.seed), objective.init_state(settings.num_classes))
    step_fn = jax.jit(functools.partial(train_step, model=model, tx=tx, objective=objective))
    times = []
    with Checkpointer(folder / "checkpoints", save_every=SAVE_EVERY) as checkpointer:
        if checkpointer.latest_step():
            state, _ = checkpointer.restore(state)
            log(f"resumed at step {int(state.step)}")
        for step in range(int(state.step), settings.steps):
            start = time.perf_counter()
            state, metrics = step_fn(state, crops(features, labels, settings, step, taps))
            loss = float(metrics["loss"])
            times.append(time.perf_counter() - start)
            if (step + 1) % 50 == 0 or step == 0:
                log(f"step {step + 1}/{settings.steps} loss {loss:.4f} ({np.median(times[1:] or times):.2f} s/step)")
            if checkpointer.is_due(step + 1) or step + 1 == settings.steps:
                checkpointer.save(step + 1, state)
                val = decoder_miou(state.variables, settings, val_features, val_labels, val_taps)
                log(f"step {step + 1}: val mIoU {100 * val['miou']:.2f}")
                with open(folder / "val_history.jsonl", "a") as f:
                    f.write(json.dumps({"step": step + 1, "val_miou": float(val["miou"])}) + "\n")
        checkpointer.wait()
    decoder = jax.device_get(state.variables)
    val = decoder_miou(decoder, settings, val_features, val_labels, val_taps)
    model_full = ERFNet(num_classes=settings.num_classes, attention=settings.attention)
    whole = {collection: {**encoder_variables()[collection], **decoder[collection]} for collection in decoder}
    write_run(folder / "run", "erfnet", model_full, whole, settings.steps, data="camvid", data_root=str(CAMVID),
              crop=(360, 480))
    result = {"settings": dataclasses.asdict(settings), "class_weights": weights,
              "objective": repr(objective),
              "val_miou": float(val["miou"]), "val_iou": [float(x) for x in val["iou"]],
              "median_step_seconds": float(np.median(times[1:])) if len(times) > 1 else None,
              "steps_this_session": len(times), "run": str(folder / "run")}
    (folder / "result.json").write_text(json.dumps(result, indent=1))
    log(f"val mIoU {100 * val['miou']:.2f}; run {folder / 'run'}")
    return folder


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=Settings.steps)
    parser.add_argument("--cache-only", action="store_true", help="cache the features and stop")
    parser.add_argument("--splits", default="train,val", help="with --cache-only: the splits (default %(default)s)")
    args = parser.parse_args(argv)
    if args.cache_only:
        for split, flip in [(s, f) for s in args.splits.split(",") for f in (False, True) if s == "train" or not f]:
            _, _, seconds = cache_features(split, flip)
            print(f"{split}{' flipped' if flip else ''}: {seconds:.2f} s per computed frame")
        return
    print(train_decoder(Settings(seed=args.seed, steps=args.steps)))


if __name__ == "__main__":
    main()
