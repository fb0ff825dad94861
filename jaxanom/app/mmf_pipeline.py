"""MMF end to end (docs/papers/mmf.md#pipeline): train the parts once, cache them, score frames with every row.

    config = MMFConfig()                       # one description of every trainable part
    pipe = MMFPipeline.build(config, "runs/mmf")   # trains or loads each part
    maps = pipe.maps(batch)                    # logits, A, D, a (with / without assistant maps), ...

Parts, each in ``root/<part>-<hash>/`` where the hash covers its settings and those of the parts
it depends on (an edited config retrains only what changed; an interrupted part resumes from
its checkpoints):

1. segmenter: the library's DeepLabV3+ (``jaxanom.app.experiment``), without attention;
2. RGB-D net (``models.rgbd``), on the segmenter's frames with disparity (docs/papers/mmf.md#depth-input);
3. synthesizer (``mmf.synthesis``), on the segmenter's frames and their ground-truth labels:
   class means (``synthesizer="class_mean"``, the CPU default) or a SPADE generator trained as a
   GAN (``"spade"``, ``mmf.gan_train``; Table 4's "lighter" synthesizer);
4. two dissimilarity nets (``models.dissimilarity``), with and without the assistant maps
   [A, D] and Ŝ_D, trained on frames the segmenter never saw (another seed: its errors there are test-like) with void
   clutter as anomaly (void -> 1, labelled -> 0); ``dissim_variants`` adds nets of the same
   training for ablations and a control (``DISSIM_VARIANTS``): without Ŝ_D, without [A, D], and
   the plain net fed the resynthesis of the ground-truth semantics (255, unknown, where void or
   anomalous) instead of the prediction's.

Synthetic data only (real-data training needs Cityscapes disparity, not wired here).
"""
from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import zipfile
import zlib
from pathlib import Path
from typing import Callable, Iterator

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_count, check_fits_memory, check_number
from jaxanom.config_codec import encode
from jaxanom.data.synthetic import SyntheticScenes
from jaxanom.data.transforms import normalize
from jaxanom.app.experiment import Experiment, build_network, jsonable, load_variables, run_training
from jaxanom.io import write_bytes_atomic
from jaxanom.losses import CrossEntropy, balanced_class_weights
from jaxanom.mmf.perceptual import anomaly_map_batch, perceptual_difference_batch
from jaxanom.mmf.postprocess import superpixel_score_batch
from jaxanom.mmf.gan_train import GANConfig, train_gan, trained_generator
from jaxanom.mmf.synthesis import ClassMeanSynthesizer, SPADESynthesizer, resynthesize
from jaxanom.mmf.training_free import SLIC_INPUTS, segment
from jaxanom.mmf.uncertainty import uncertainty_maps_batch
from jaxanom.models.dissimilarity import DissimilarityNet, anomaly_probability
from jaxanom.models.patch_discriminator import MultiscaleDiscriminator
from jaxanom.models.resnet import RESNETS, ResNet
from jaxanom.models.rgbd import RGBDNet, depth_input
from jaxanom.models.spade_generator import SPADEGenerator
from jaxanom.train.segmenter import TrainConfig, train
from jaxanom.train.restore import trained_variables
from jaxanom.train.optim import OptimConfig

_SEGMENTER = Experiment(
    attention=None, train_frames=128, height=64, width=128, crop=(64, 128), scale_range=(0.75, 1.25), batch_size=8,
    train=TrainConfig(run_dir="", steps=400, eval_every=400, save_every=200, keep=1,
                      optim=OptimConfig(name="adamw", lr=2e-3, weight_decay=1e-4, warmup_steps=20)))


@dataclasses.dataclass(frozen=True)
class MMFConfig:
    """Every trainable part of MMF on synthetic scenes (sizes for a CPU; ``quick()`` for tests).

    ``segmenter``: the segmenter's experiment (its frames, size and schedule are the pipeline's);
    ``rgbd_*``: RGB-D net backbone, decoder width, steps; ``dissim_*``: dissimilarity nets' width
    multiplier, steps, learning rate (Adam, betas 0.9 / 0.999), frames and void clutter per frame,
    ``dissim_balance``: class-weighted cross-entropy (``losses.balanced_class_weights``);
    ``dissim_variants``: names of ``DISSIM_VARIANTS`` trained besides ``mmf`` and ``resynthesis``;
    ``synthesizer``: ``"class_mean"`` or ``"spade"``; ``gan_*`` (SPADE only): steps, base width nf,
    upsamplings n, SPADE hidden width, critic layers (docs/papers/mmf.md#spade-generator: nf = 8, n = 3);
    ``slic_step``: SLIC grid step S in pixels, None: ``superpixels.scaled_step`` of the frame
    (8 px at 256x512, K ~ 2048 at any size; docs/papers/mmf.md#superpixel-step); ``slic_input``: what SLIC segments,
    ``"image"`` (its Lab, as the paper's Algorithms 1-2) or ``"anomaly"`` (the map Eq. 6 scores, scaled to [0, 100]: the
    paper's Sec. III-B / Fig. 4, one segmentation per dissimilarity net); ``slic_connectivity``:
    superpixels made connected (``superpixels.slic``); ``batch_size`` for the RGB-D and
    dissimilarity nets.
    """

    segmenter: Experiment = _SEGMENTER
    rgbd_backbone: str = "resnet_tiny"
    rgbd_channels: int = 32
    rgbd_steps: int = 200
    dissim_width: float = 1 / 8
    dissim_steps: int = 300
    dissim_lr: float = 1e-3
    dissim_frames: int = 96
    dissim_balance: bool = True
    dissim_variants: tuple[str, ...] = ()
    void_objects: int = 4
    batch_size: int = 8
    slic_step: int | None = None
    slic_input: str = "image"
    slic_connectivity: bool = False
    synthesizer: str = "class_mean"
    gan_steps: int = 300
    gan_nf: int = 8
    gan_upsamples: int = 3
    gan_hidden: int = 32
    gan_layers: int = 3

    def __post_init__(self):
        s = self.segmenter
        if s.data != "synthetic" or s.height % 8 or s.width % 8 or tuple(s.crop) != (s.height, s.width):
            raise ValueError(f"segmenter: expected synthetic data, height and width divisible by 8 and crop = "
                             f"(height, width), got {s.data}, {s.height} x {s.width}, crop {s.crop}")
        if self.rgbd_backbone not in RESNETS:
            raise ValueError(f"rgbd_backbone: expected one of {sorted(RESNETS)}, got {self.rgbd_backbone!r}")
        for name in ("rgbd_channels", "rgbd_steps", "dissim_steps", "dissim_frames", "batch_size", "gan_steps",
                     "gan_nf", "gan_upsamples", "gan_hidden", "gan_layers"):
            check_count(name, getattr(self, name))
        check_count("void_objects", self.void_objects, minimum=0)
        if self.slic_step is not None:  # None: scaled with the frame (superpixels.scaled_step)
            check_count("slic_step", self.slic_step, maximum=min(s.height, s.width))
        if not isinstance(self.dissim_variants, tuple) or not set(self.dissim_variants) <= set(DISSIM_VARIANTS):
            raise ValueError(f"dissim_variants: expected a tuple of names from {tuple(DISSIM_VARIANTS)}, "
                             f"got {self.dissim_variants!r}")
        if self.slic_input not in SLIC_INPUTS:
            raise ValueError(f"slic_input: expected one of {SLIC_INPUTS}, got {self.slic_input!r}")
        for name in ("dissim_balance", "slic_connectivity"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name}: expected true or false, got {getattr(self, name)!r}")
        check_number("dissim_width", self.dissim_width, 0.0, open_low=True)
        check_number("dissim_lr", self.dissim_lr, 0.0, open_low=True)
        # a lower bound of an RGB-D or dissimilarity batch: float32 RGB and an int32 label per pixel
        check_fits_memory("batch_size", self.batch_size, s.height * s.width * 16, "frames of the RGB-D net")
        if self.synthesizer not in SYNTHESIZERS:
            raise ValueError(f"synthesizer: expected one of {SYNTHESIZERS}, got {self.synthesizer!r}")
        if s.height % 2 ** self.gan_upsamples or s.width % 2 ** self.gan_upsamples:
            raise ValueError(f"gan_upsamples: expected 2^n to divide the segmenter's {s.height} x {s.width}, "
                             f"got n = {self.gan_upsamples}")

    @classmethod
    def quick(cls) -> "MMFConfig":
        """A smoke run of the same path at tiny sizes (tests, ``demo mmf --quick``; most of its time is compiling)."""
        seg = dataclasses.replace(_SEGMENTER, train_frames=4, height=32, width=64, crop=(32, 64), batch_size=4,
                                  train=dataclasses.replace(_SEGMENTER.train, steps=2, eval_every=2, save_every=2,
                                                            optim=dataclasses.replace(_SEGMENTER.train.optim,
                                                                                      warmup_steps=0)))
        return cls(segmenter=seg, rgbd_channels=8, rgbd_steps=2, dissim_width=1 / 16, dissim_steps=2,
                   dissim_frames=4, batch_size=4)

    def to_dict(self) -> dict:
        """Every setting as plain JSON values (the segmenter's as its experiment JSON)."""
        return {**encode(self), "segmenter": jsonable(self.segmenter)}

    def key(self, *fields: str) -> str:
        """A 12-hex hash of the named settings (the segmenter's as its JSON)."""
        settings = self.to_dict()
        values = {f: settings[f] for f in fields}
        return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:12]

    def part_key(self, part: str) -> str:
        """The hash naming a trained part's folder (``segmenter``, ``rgbd``, ``synthesizer``,
        ``spade``, ``dissimilarity``): its settings and those of the parts it depends on (the
        dissimilarity nets depend on the SPADE settings only when they see its resynthesis)."""
        spade = ("synthesizer",) + _SPADE_FIELDS if part == "dissimilarity" and self.synthesizer == "spade" else ()
        key = self.key(*_PARTS[part], *spade)
        if part in _REVISIONS:  # a changed network or training: older folders are not reused
            key = hashlib.sha256(f"{key} {_REVISIONS[part]}".encode()).hexdigest()[:12]
        return key


SYNTHESIZERS = ("class_mean", "spade")
# dissimilarity nets: name -> (uncertainty channels [A, D], reads S_D, resynthesis of the ground truth)
DISSIM_NETS = {"mmf": (2, True, False), "resynthesis": (0, False, False)}
DISSIM_VARIANTS = {"no_depth": (2, False, False), "no_uncertainty": (0, True, False),
                   "truth_resynthesis": (0, False, True)}
# a part's revision text is hashed into its folder key, so a changed network or training never reuses older
# folders. Rewording the text alone (to "revision 2: ...") made cached dissimilarity parts retrain once.
_REVISIONS = {"dissimilarity": "revision 2: correlation concatenated after the prior product"}
_SLIC_FIELDS = ("slic_step", "slic_input", "slic_connectivity")  # scoring only: in no part's key
# each variant is its own folder (its name in it): the list of them is in no part's key
_SPADE_FIELDS = ("gan_steps", "gan_nf", "gan_upsamples", "gan_hidden", "gan_layers")
# the class-mean parts' keys leave out the SPADE settings (caches of class-mean runs stay valid)
_PARTS = {"segmenter": ("segmenter",),
          "rgbd": ("segmenter", "rgbd_backbone", "rgbd_channels", "rgbd_steps", "batch_size"),
          "synthesizer": ("segmenter",),
          "spade": ("segmenter", "batch_size") + _SPADE_FIELDS,
          "dissimilarity": tuple(f.name for f in dataclasses.fields(MMFConfig)
                                 if f.name not in ("synthesizer", "dissim_variants") + _SLIC_FIELDS + _SPADE_FIELDS)}


def training_stream(arrays: dict[str, np.ndarray], batch_size: int, seed: int) -> Iterator[dict]:
    """Endless random batches (with horizontal flips) of equally long host arrays; a pure
    function of ``seed`` and the step, so a resumed run may skip the batches it used."""
    count = len(arrays["image"])
    for step in range(1 << 62):
        rng = np.random.default_rng([seed, step])
        index = rng.choice(count, batch_size, replace=count < batch_size)
        flip = rng.random(batch_size) < 0.5
        batch = {}
        for name, value in arrays.items():
            chosen = value[index]
            batch[name] = np.where(flip.reshape((-1,) + (1,) * (chosen.ndim - 1)), chosen[:, :, ::-1], chosen)
        yield batch


def _train_config(run_dir: Path, steps: int, lr: float, seed: int, progress: bool, adam: bool = False,
                  class_weights: tuple[float, ...] | None = None) -> TrainConfig:
    optim = OptimConfig(name="adamw", lr=lr, weight_decay=0.0 if adam else 1e-4, poly_power=0.0 if adam else 0.9)
    return TrainConfig(run_dir=str(run_dir), steps=steps, seed=seed, optim=optim, eval_every=steps,
                       save_every=max(1, steps // 2), keep=1, progress=progress,
                       objective=CrossEntropy(class_weights=class_weights))


def _run_dir(config: MMFConfig, root: Path, part: str, name: str = "") -> Path:
    """``root/<part>[-<name>]-<hash of the part's settings>``."""
    return root / "-".join(filter(None, (part, name, config.part_key(part))))


def _rgbd_model(config: MMFConfig) -> RGBDNet:
    return RGBDNet(config.segmenter.num_classes, config.rgbd_backbone, config.rgbd_channels,
                   max(1, config.rgbd_channels // 4))


def _rgbd_train_config(config: MMFConfig, run: Path, progress: bool) -> TrainConfig:
    return _train_config(run, config.rgbd_steps, 2e-3, config.segmenter.train.seed, progress)


def _dissimilarity_model(config: MMFConfig, name: str) -> DissimilarityNet:
    channels, depth, _ = {**DISSIM_NETS, **DISSIM_VARIANTS}[name]
    return DissimilarityNet(config.segmenter.num_classes, uncertainty_channels=channels, use_depth=depth,
                            width=config.dissim_width)


def dissimilarity_names(config: MMFConfig) -> tuple[str, ...]:
    """The dissimilarity nets a pipeline of ``config`` trains: ``mmf``, ``resynthesis``, its variants."""
    return (*DISSIM_NETS, *config.dissim_variants)


def _net_inputs(inputs: dict, name: str, model: DissimilarityNet) -> dict:
    """The extra inputs of net ``name``; the ground-truth resynthesis for the control net."""
    truth = {**DISSIM_NETS, **DISSIM_VARIANTS}[name][2]
    return {k: inputs["resynthesis_truth" if truth and k == "resynthesis" else k] for k in model.extra_inputs}


def _dissimilarity_train_config(config: MMFConfig, root: Path, name: str, progress: bool,
                                labels: np.ndarray | None = None) -> TrainConfig:
    """The nets' training run; with ``dissim_balance`` and the training ``labels``, cross-entropy
    weighted by ``losses.balanced_class_weights`` (void clutter is rare: docs/papers/mmf.md#dissimilarity-training)."""
    weights = (tuple(float(w) for w in balanced_class_weights(labels, 2))
               if config.dissim_balance and labels is not None else None)
    return _train_config(_run_dir(config, root, "dissimilarity", name), config.dissim_steps, config.dissim_lr,
                         config.segmenter.train.seed, progress, adam=True, class_weights=weights)


def _gan_models(config: MMFConfig) -> tuple[SPADEGenerator, MultiscaleDiscriminator]:
    classes = config.segmenter.num_classes
    return (SPADEGenerator(classes, config.gan_nf, config.gan_upsamples, config.gan_hidden),
            MultiscaleDiscriminator(classes, config.gan_nf, config.gan_layers))


def _gan_config(config: MMFConfig, root: Path, progress: bool) -> GANConfig:
    return GANConfig(str(root / f"synthesizer-spade-{config.part_key('spade')}"), steps=config.gan_steps,
                     seed=config.segmenter.train.seed, save_every=max(1, config.gan_steps // 2), keep=1,
                     progress=progress)


def load_synthesizer(config: MMFConfig, root: Path) -> ClassMeanSynthesizer | SPADESynthesizer:
    """The synthesizer ``build_synthesizer`` made under ``root``, read-only; ValueError if it is
    missing or (SPADE) its training stopped early."""
    if config.synthesizer == "spade":
        generator, critic = _gan_models(config)
        seg = config.segmenter
        example = {"image": np.zeros((1, seg.height, seg.width, 3), np.uint8),
                   "label": np.zeros((1, seg.height, seg.width), np.int32)}
        return SPADESynthesizer(generator, trained_generator(_gan_config(config, root, False), generator, critic, example))
    synth_file = _run_dir(config, root, "synthesizer").with_suffix(".npz")
    if not synth_file.is_file():
        raise ValueError(f"{synth_file}: no such file")
    return _class_means(synth_file, config.segmenter.num_classes)


def _class_means(synth_file: Path, num_classes: int) -> ClassMeanSynthesizer:
    """The cached class means in ``synth_file``; ValueError naming it when it is not one (no pickles read)."""
    try:
        with np.load(synth_file, allow_pickle=False) as data:
            means = np.asarray(data["means"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as error:
        problem = "it holds Python objects" if "allow_pickle" in str(error) else f"{type(error).__name__}: {error}"
        raise ValueError(f"{synth_file}: not class means written by jaxanom ({problem}); "
                         "delete it to refit them") from None
    floats = np.issubdtype(means.dtype, np.floating)
    if means.shape != (num_classes + 1, 3) or not floats or not np.isfinite(means).all():
        raise ValueError(f"{synth_file}: expected finite float class means of shape ({num_classes + 1}, 3), got "
                         f"{means.dtype} {means.shape}; delete it to refit them")
    return ClassMeanSynthesizer(means)


def build_synthesizer(config: MMFConfig, root: Path, frames: list[dict],
                      progress: bool = True) -> ClassMeanSynthesizer | SPADESynthesizer:
    """The synthesizer of ``config.synthesizer`` for ``frames`` (``image``, ground-truth ``label``),
    loaded from ``root`` when cached: class means in ``synthesizer-<hash>.npz``, or a SPADE
    generator trained (resumably) in ``synthesizer-spade-<hash>/``."""
    num_classes, seed = config.segmenter.num_classes, config.segmenter.train.seed
    if config.synthesizer == "spade":
        generator, critic = _gan_models(config)
        gan = _gan_config(config, root, progress)
        arrays = {"image": np.stack([f["image"] for f in frames]),
                  "label": np.stack([f["label"] for f in frames]).astype(np.int32)}
        state = train_gan(gan, generator, critic, training_stream(arrays, config.batch_size, seed + 3))
        return SPADESynthesizer(generator, jax.device_get(state.generator_variables))
    synth_file = _run_dir(config, root, "synthesizer").with_suffix(".npz")
    if synth_file.exists():
        return _class_means(synth_file, num_classes)
    synthesizer = ClassMeanSynthesizer.fit(frames, num_classes)
    buffer = io.BytesIO()
    np.savez(buffer, means=synthesizer.means)
    write_bytes_atomic(synth_file, buffer.getvalue())
    return synthesizer


@dataclasses.dataclass
class MMFPipeline:
    """The trained parts and the jitted map computation (``maps``)."""

    config: MMFConfig
    segmenter: tuple          # (model, variables)
    rgbd: tuple
    synthesizer: ClassMeanSynthesizer | SPADESynthesizer
    dissimilarity: dict       # {"mmf": (model, variables), "resynthesis": (model, variables)}

    @classmethod
    def build(cls, config: MMFConfig, root: str | Path, *, progress: bool = True,
              log: Callable[[str], None] = print) -> "MMFPipeline":
        """Train (or load, or resume) every part under ``root``; see the module docstring."""
        root = Path(root)
        seg_cfg = config.segmenter
        seed = seg_cfg.train.seed
        log("MMF 1/4: segmenter")
        seg_vars = run_training(seg_cfg, _run_dir(config, root, "segmenter"),
                                progress=progress, validate=False)
        segmenter = (build_network(seg_cfg), seg_vars)

        log("MMF 2/4: RGB-D network")
        frames = [SyntheticScenes("train", seg_cfg.train_frames, seed, height=seg_cfg.height, width=seg_cfg.width,
                                  disparity=True)[i] for i in range(seg_cfg.train_frames)]
        arrays = {"image": np.stack([f["image"] for f in frames]),
                  "label": np.stack([f["label"] for f in frames]).astype(np.int32),
                  "depth": depth_input(np.stack([f["disparity"] for f in frames]), seg_cfg.width)[..., None]}
        rgbd_model = _rgbd_model(config)
        run = _run_dir(config, root, "rgbd")
        state = train(_rgbd_train_config(config, run, progress), rgbd_model,
                      training_stream(arrays, config.batch_size, seed))
        rgbd = (rgbd_model, jax.device_get(state.variables))

        log(f"MMF 3/4: synthesizer ({config.synthesizer})")
        synthesizer = build_synthesizer(config, root, frames, progress)

        pipe = cls(config, segmenter, rgbd, synthesizer, {})
        log("MMF 4/4: dissimilarity networks (with and without assistant maps)")
        dissim_frames = SyntheticScenes("train", config.dissim_frames, seed + 1, height=seg_cfg.height,
                                        width=seg_cfg.width, disparity=True, void_objects=config.void_objects)
        batches = []
        for j in range(0, len(dissim_frames), config.batch_size):
            chunk = [dissim_frames[i] for i in range(j, min(j + config.batch_size, len(dissim_frames)))]
            batches.append(pipe._dissimilarity_inputs(chunk, pipe._network_maps(chunk)))
        arrays = {k: np.concatenate([b[k] for b in batches]) for k in batches[0]}
        for name in dissimilarity_names(config):
            model = _dissimilarity_model(config, name)
            data = {"image": arrays["image"], "label": arrays["label"], **_net_inputs(arrays, name, model)}
            state = train(_dissimilarity_train_config(config, root, name, progress, arrays["label"]),
                          model, training_stream(data, config.batch_size, seed + 2))
            pipe.dissimilarity[name] = (model, jax.device_get(state.variables))
        return pipe

    @classmethod
    def load(cls, config: MMFConfig, root: str | Path) -> "MMFPipeline":
        """The parts ``build`` trained under ``root``, read-only (nothing is trained or written);
        ValueError naming the part that is missing or unfinished."""
        root = Path(root)
        seg = config.segmenter
        shape = (1, seg.height, seg.width)
        try:
            _, seg_vars = load_variables(_run_dir(config, root, "segmenter"))
            rgbd_model = _rgbd_model(config)
            rgbd_vars = trained_variables(_rgbd_train_config(config, _run_dir(config, root, "rgbd"), False), rgbd_model,
                                          {"image": np.zeros((*shape, 3), np.uint8),
                                           "depth": np.zeros((*shape, 1), np.float32)}, complete=True)
            synthesizer = load_synthesizer(config, root)
            dissimilarity = {}
            for name in dissimilarity_names(config):
                model = _dissimilarity_model(config, name)
                example = {"image": np.zeros((*shape, 3), np.float32), "resynthesis": np.zeros((*shape, 3), np.float32),
                           "semantic": np.zeros(shape, np.int32), "semantic_depth": np.zeros(shape, np.int32),
                           "uncertainty": np.zeros((*shape, 2), np.float32)}
                variables = trained_variables(_dissimilarity_train_config(config, root, name, False), model,
                                              {k: example[k] for k in ("image", *model.extra_inputs)}, complete=True)
                dissimilarity[name] = (model, variables)
        except ValueError as error:
            raise ValueError(f"mmf pipeline in {root}: {error} (train it with `jaxanom demo mmf`)") from None
        return cls(config, (build_network(seg), seg_vars), (rgbd_model, rgbd_vars), synthesizer, dissimilarity)

    def _network_maps(self, frames: list[dict]) -> dict[str, np.ndarray]:
        """Segmenter, RGB-D net, resynthesis and Eqs. 1-4 for frames with ``image`` and ``disparity``."""
        images = np.stack([f["image"] for f in frames])
        disparity = np.stack([f["disparity"] for f in frames])
        out = _forward(self.segmenter, self.rgbd, self.synthesizer, images,
                       depth_input(disparity, images.shape[2])[..., None])
        return {k: np.asarray(v) for k, v in out.items()}

    def semantics(self, frames: list[dict]) -> tuple[np.ndarray, np.ndarray]:
        """(Ŝ of the segmenter, Ŝ_D of the RGB-D net), int32 (B, H, W), of frames with ``image`` and ``disparity``."""
        out = self._network_maps(frames)
        return out["prediction"], out["prediction_depth"]

    def _dissimilarity_inputs(self, frames: list[dict], out: dict) -> dict[str, np.ndarray]:
        """The dissimilarity nets' inputs (and void-as-anomaly labels where frames have ``void``);
        ``resynthesis_truth`` (of the frames' ground-truth ``semantic``) when the control net is trained."""
        images = np.stack([f["image"] for f in frames])
        inputs = {"image": normalize(images), "resynthesis": out["resynthesis_normalized"],
                  "semantic": out["prediction"], "semantic_depth": out["prediction_depth"],
                  "uncertainty": np.stack([out["anomaly"], out["distance"]], axis=-1)}
        if "truth_resynthesis" in self.config.dissim_variants:
            semantic = np.stack([f["semantic"] for f in frames]).astype(np.int32)
            r = self.synthesizer.synthesize_batch(semantic)
            inputs["resynthesis_truth"] = np.asarray(normalize(jnp.round(r * 255).astype(jnp.uint8)))
        if "void" in frames[0]:  # void as anomaly (1), labelled pixels 0
            inputs["label"] = np.stack([f["void"] for f in frames]).astype(np.int32)
        return inputs

    def maps(self, frames: list[dict]) -> dict[str, np.ndarray]:
        """Every map of MMF for a list of equally sized frames (``image``, ``disparity``):
        ``logits``, ``entropy`` (U), ``distance`` (D), ``perceptual`` (L), ``anomaly`` (A),
        ``resynthesis`` (r, [0, 1]), ``mmf`` / ``resynthesis_score`` (a of the two nets),
        ``dissim_<variant>`` (a of each variant net), ``superpixels`` and ``num_segments`` (SLIC of
        ``config.slic_input``; with ``"anomaly"``, ``superpixels`` segments ``mmf``,
        ``superpixels_resynthesis`` segments ``resynthesis_score`` and ``superpixels_<variant>``
        each variant's map)."""
        out = self._network_maps(frames)
        inputs = self._dissimilarity_inputs(frames, out)
        names = {"mmf": "mmf", "resynthesis": "resynthesis_score"}
        for name, (model, variables) in self.dissimilarity.items():
            logits = _dissimilarity_forward(model, variables, inputs["image"], _net_inputs(inputs, name, model))
            out[names.get(name, f"dissim_{name}")] = np.asarray(anomaly_probability(logits))
        c = self.config
        targets = {"superpixels": out["mmf"], "superpixels_resynthesis": out["resynthesis_score"],
                   **{f"superpixels_{v}": out[f"dissim_{v}"] for v in self.dissimilarity if v not in names}}
        out.update(segment(np.stack([f["image"] for f in frames]), targets, step=c.slic_step,
                           slic_input=c.slic_input, connectivity=c.slic_connectivity))
        return out


_JITTED: dict = {}  # one jitted function per (frozen, hashable) Flax module or pair of modules


def _dissimilarity_forward(model, variables, images, kw):
    if model not in _JITTED:
        _JITTED[model] = jax.jit(lambda v, x, extra: model.apply(v, x, **extra)["logits"])
    return _JITTED[model](variables, images, kw)


def _forward(segmenter, rgbd, synthesizer, images, depth) -> dict:
    """Segmenter, RGB-D net, resynthesis and the maps of Eqs. 1-4 for a batch (one jitted call)."""
    (seg_model, seg_vars), (rgbd_model, rgbd_vars) = segmenter, rgbd
    generator = getattr(synthesizer, "model", None)  # None: class means
    key = (seg_model, rgbd_model, generator)
    if key not in _JITTED:
        _JITTED[key] = jax.jit(lambda *args: _maps(seg_model, rgbd_model, generator, *args))
    return _JITTED[key](seg_vars, rgbd_vars, synthesizer.arrays, images, depth)


def _maps(seg_model, rgbd_model, generator, seg_vars, rgbd_vars, synth_arrays, images, depth) -> dict:
    x = normalize(images)
    logits = seg_model.apply(seg_vars, x)["logits"]
    maps = uncertainty_maps_batch(logits)
    prediction = maps["prediction"]
    resynthesis = resynthesize(generator, synth_arrays, prediction)
    r, perceptual, anomaly = _perceptual(seg_model, seg_vars, x, resynthesis, maps["entropy"])
    depth_logits = rgbd_model.apply(rgbd_vars, x, depth=depth)["logits"]
    return {"logits": logits, "entropy": maps["entropy"], "distance": maps["distance"], "road": maps["road"],
            "prediction": prediction, "prediction_depth": jnp.argmax(depth_logits, -1).astype(jnp.int32),
            "resynthesis": resynthesis, "resynthesis_normalized": r, "perceptual": perceptual, "anomaly": anomaly}


def _perceptual(seg_model, seg_vars, x, resynthesis, entropy) -> tuple:
    """(r normalised, L of Eq. 3, A of Eq. 4) for normalised images x and r in [0, 1] (B, H, W, 3):
    the perceptual features are the segmenter's own ResNet stages (docs/papers/mmf.md#perceptual-difference)."""
    r = normalize(jnp.round(resynthesis * 255).astype(jnp.uint8))
    backbone = ResNet(RESNETS[seg_model.backbone], seg_model.output_stride)
    sub = {"params": seg_vars["params"]["backbone"], "batch_stats": seg_vars["batch_stats"]["backbone"]}
    fx, fr = backbone.apply(sub, x), backbone.apply(sub, r)
    taps = [f"layer{i}" for i in range(1, 5)]
    perceptual = perceptual_difference_batch([fx[t] for t in taps], [fr[t] for t in taps], x.shape[1:3])
    return r, perceptual, anomaly_map_batch(entropy, perceptual)


def module_calls(pipe: MMFPipeline, frames: list[dict]) -> dict[str, Callable[[], object]]:
    """One zero-argument call per module of MMF on ``frames`` (``image``, ``disparity``), each
    jitted on its own with its inputs computed beforehand, for per-module timings (the paper's
    Table 3): ``segmentation``, ``uncertainty`` (Eqs. 1-2), ``synthesis``, ``perceptual difference``
    (Eqs. 3-4), ``depth`` (RGB-D net), ``dissimilarity`` (the MMF net) and ``post-processor``
    (SLIC of ``config.slic_input`` and Eq. 6, on the host where SLIC's labels are read)."""
    (seg_model, seg_vars), (rgbd_model, rgbd_vars) = pipe.segmenter, pipe.rgbd
    generator, arrays = getattr(pipe.synthesizer, "model", None), pipe.synthesizer.arrays
    images = np.stack([f["image"] for f in frames])
    x = normalize(images)
    depth = depth_input(np.stack([f["disparity"] for f in frames]), images.shape[2])[..., None]
    segment_fn = jax.jit(lambda v, x: seg_model.apply(v, x)["logits"])
    uncertainty_fn = jax.jit(uncertainty_maps_batch)
    synthesis_fn = jax.jit(lambda a, p: resynthesize(generator, a, p))
    perceptual_fn = jax.jit(lambda v, x, r, u: _perceptual(seg_model, v, x, r, u))
    depth_fn = jax.jit(lambda v, x, d: rgbd_model.apply(v, x, depth=d)["logits"])
    logits = segment_fn(seg_vars, x)
    maps = uncertainty_fn(logits)
    resynthesis = synthesis_fn(arrays, maps["prediction"])
    out = pipe.maps(frames)
    inputs = pipe._dissimilarity_inputs(frames, pipe._network_maps(frames))
    model, variables = pipe.dissimilarity["mmf"]
    extra = _net_inputs(inputs, "mmf", model)
    c = pipe.config

    def post():
        labels = segment(images, {"superpixels": out["mmf"]}, step=c.slic_step, slic_input=c.slic_input,
                         connectivity=c.slic_connectivity)
        return superpixel_score_batch(out["mmf"], out["road"], labels["superpixels"], labels["num_segments"])

    return {"segmentation": lambda: segment_fn(seg_vars, x), "uncertainty": lambda: uncertainty_fn(logits),
            "synthesis": lambda: synthesis_fn(arrays, maps["prediction"]),
            "perceptual difference": lambda: perceptual_fn(seg_vars, x, resynthesis, maps["entropy"]),
            "depth": lambda: depth_fn(rgbd_vars, x, depth),
            "dissimilarity": lambda: _dissimilarity_forward(model, variables, inputs["image"], extra),
            "post-processor": post}


def scored_batches(pipe: MMFPipeline, source, batch_size: int, keep: int = 0, kept: list | None = None):
    """Batches ``{"logits", "label", "roi"?, "mmf_maps"}`` for ``evaluate.anomaly_results``; the
    first ``keep`` frames' maps are appended to ``kept`` (for pictures)."""
    for start in range(0, len(source), batch_size):
        frames = [source[i] for i in range(start, min(start + batch_size, len(source)))]
        maps = pipe.maps(frames)
        if kept is not None:
            for i, frame in enumerate(frames[:max(0, keep - start)]):
                kept.append((frame, {k: v[i] for k, v in maps.items() if k != "num_segments"}))
        yield scored_batch(frames, maps)


def scored_batch(frames: list[dict], maps: dict, net: str = "mmf") -> dict:
    """One batch for ``evaluate.anomaly_results`` from ``MMFPipeline.maps`` of ``frames``; ``net``
    (``"mmf"`` or a variant of ``DISSIM_VARIANTS``) is the net scored by the ``mmf_raw`` / ``mmf`` rows."""
    source = "" if net == "mmf" else f"_{net}"
    if net != "mmf" and f"dissim_{net}" not in maps:
        raise ValueError(f"net: expected 'mmf' or a trained variant, got {net!r}")
    mmf = maps["mmf"] if net == "mmf" else maps[f"dissim_{net}"]
    segments = maps.get(f"superpixels{source}", maps["superpixels"])  # SLIC of this map, if it has its own
    batch = {"logits": maps["logits"], "label": np.stack([f["label"] for f in frames]),
             "mmf_maps": {"mmf": mmf, "resynthesis": maps["resynthesis_score"], "num_segments": maps["num_segments"],
                          "superpixels": segments,
                          **({"superpixels_resynthesis": maps["superpixels_resynthesis"]}
                             if "superpixels_resynthesis" in maps else {})}}
    if "roi" in frames[0]:  # the road region of interest, where the dataset has one
        batch["roi"] = np.stack([f["roi"] for f in frames])
    return batch
