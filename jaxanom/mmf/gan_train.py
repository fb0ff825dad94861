"""Training of the SPADE synthesizer against its critic (docs/papers/mmf.md#spade-generator): two Adam optimisers, one step.

    config = GANConfig(run_dir="runs/spade", steps=2000)
    state = train_gan(config, SPADEGenerator(19, nf=8), MultiscaleDiscriminator(19, nf=8), batches)

``batches``: an iterable of ``{"image": (B, H, W, 3) uint8 RGB or float in [0, 1], "label":
(B, H, W) int (the semantic map to synthesise from; 255 = unknown)}``, deterministic (a resumed
run skips the batches already used).
Each step (``make_gan_step``) first updates the generator on hinge + 10 feature matching + 10 L1
(``mmf.gan``) with the critic fixed, then the critic on the hinge loss, with the same batch and
the fake of the generator before its update (as pix2pixHD; SPADE's trainer draws a new fake
after the update). Adam with beta = (0, 0.999), G 1e-4, D 4e-4 (TTUR, [34]).

The host loop is ``jaxanom.train.run_loop``'s, as the segmenter's (orbax checkpoints every
``save_every`` and at the end, resume from the newest, a stop on a non-finite loss or gradient
norm), with ``log.jsonl`` / TensorBoard and a progress bar, on one device: the generator's
BatchNorm uses the statistics of the local batch.
"""
from __future__ import annotations

import dataclasses
import functools
import os
from typing import Any, Iterable

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxanom.mmf.gan import FEATURE_WEIGHT, L1_WEIGHT, generator_loss, hinge_discriminator_loss
from jaxanom.models.spade_generator import UNKNOWN
from jaxanom.train.segmenter import check_batch
from jaxanom.train.restore import restore_run
from jaxanom.train.run_loop import Checkpoints, progress_bar, run_loop
from jaxanom.train.runlog import RunLog


@dataclasses.dataclass(frozen=True)
class GANConfig:
    """A GAN run; defaults as in docs/papers/mmf.md#spade-generator (Adam G 1e-4 / D 4e-4, betas (0, 0.999), FM and L1 x10)."""

    run_dir: str
    steps: int = 2000
    seed: int = 0
    g_lr: float = 1e-4
    d_lr: float = 4e-4
    betas: tuple[float, float] = (0.0, 0.999)
    feature_weight: float = FEATURE_WEIGHT
    l1_weight: float = L1_WEIGHT
    save_every: int = 500
    keep: int = 1
    progress: bool = True
    log_every: int = 50  # steps between reads of the losses (each step still gets its line in the log)

    def __post_init__(self):
        for name in ("steps", "save_every", "keep", "log_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected >= 1, got {getattr(self, name)}")
        if not (self.g_lr > 0 and self.d_lr > 0):
            raise ValueError(f"g_lr, d_lr: expected > 0, got {self.g_lr}, {self.d_lr}")


@flax.struct.dataclass
class GANState:
    """Both networks' parameters and Adam states, the generator's BatchNorm statistics, the step."""

    g_params: Any
    g_batch_stats: Any
    d_params: Any
    g_opt: Any
    d_opt: Any
    step: jax.Array

    @property
    def generator_variables(self) -> dict:
        """``{"params", "batch_stats"}`` as ``SPADEGenerator.apply`` wants them."""
        return {"params": self.g_params, "batch_stats": self.g_batch_stats}


def _optimizers(config: GANConfig) -> tuple[optax.GradientTransformation, optax.GradientTransformation]:
    b1, b2 = config.betas
    return optax.adam(config.g_lr, b1=b1, b2=b2), optax.adam(config.d_lr, b1=b1, b2=b2)


@functools.lru_cache(maxsize=4)
def _jitted_init(generator, discriminator):
    def init(key, image, semantic):
        g_key, d_key = jax.random.split(key)
        return generator.init(g_key, semantic, train=False), discriminator.init(d_key, image, semantic)

    return jax.jit(init)


def init_gan_state(config: GANConfig, generator, discriminator, batch: dict) -> GANState:
    """A step-0 state: both networks initialised from ``config.seed`` on the first example of ``batch``.

    The key is JAX's ``rbg`` generator: XLA:CPU compiles the default threefry draws of a few
    hundred small parameter arrays several times more slowly. The state is committed to the first
    device, as a restored one is: a resumed run then reuses the step compiled for a fresh one."""
    image, semantic = _inputs(batch)
    g_vars, d_vars = _jitted_init(generator, discriminator)(jax.random.key(config.seed, impl="rbg"),
                                                            image[:1], semantic[:1])
    g_tx, d_tx = _optimizers(config)
    state = GANState(g_params=g_vars["params"], g_batch_stats=g_vars["batch_stats"], d_params=d_vars["params"],
                     g_opt=g_tx.init(g_vars["params"]), d_opt=d_tx.init(d_vars["params"]),
                     step=jnp.zeros((), jnp.int32))
    return jax.device_put(state, jax.local_devices()[0])


def make_gan_step(config: GANConfig, generator, discriminator):
    """The pure step ``(state, image (B, H, W, 3) float [0, 1], semantic (B, H, W)) -> (state, metrics)``."""
    g_tx, d_tx = _optimizers(config)

    def critic(d_params, first, second, semantic):
        """The critic on two images of one batch in one call (instance norm is per example)."""
        out = discriminator.apply({"params": d_params}, jnp.concatenate([first, second]),
                                  jnp.concatenate([semantic, semantic]))
        return jax.tree.map(lambda x: jnp.split(x, 2), out)

    def step(state: GANState, image: jax.Array, semantic: jax.Array) -> tuple[GANState, dict]:
        def g_objective(g_params):
            out, updates = generator.apply({"params": g_params, "batch_stats": state.g_batch_stats}, semantic,
                                           train=True, mutable=["batch_stats"])
            fake = out["image"]
            out = critic(state.d_params, fake, image, semantic)
            fake_logits = [pair[0] for pair in out["logits"]]
            fake_features, real_features = ([[pair[i] for pair in scale] for scale in out["features"]] for i in (0, 1))
            loss, parts = generator_loss(fake_logits, real_features, fake_features, fake, image,
                                         config.feature_weight, config.l1_weight)
            return loss, (parts, updates["batch_stats"], fake)

        (g_loss, (parts, batch_stats, fake)), g_grads = jax.value_and_grad(g_objective, has_aux=True)(state.g_params)
        g_updates, g_opt = g_tx.update(g_grads, state.g_opt, state.g_params)
        fake = jax.lax.stop_gradient(fake)

        def d_objective(d_params):
            logits = critic(d_params, image, fake, semantic)["logits"]
            return hinge_discriminator_loss([pair[0] for pair in logits], [pair[1] for pair in logits])

        d_loss, d_grads = jax.value_and_grad(d_objective)(state.d_params)
        d_updates, d_opt = d_tx.update(d_grads, state.d_opt, state.d_params)
        new = state.replace(g_params=optax.apply_updates(state.g_params, g_updates), g_batch_stats=batch_stats,
                            d_params=optax.apply_updates(state.d_params, d_updates), g_opt=g_opt, d_opt=d_opt,
                            step=state.step + 1)
        metrics = {"g_loss": g_loss, "d_loss": d_loss, **parts,
                   "g_grad_norm": optax.tree.norm(g_grads), "d_grad_norm": optax.tree.norm(d_grads)}
        return new, metrics

    return step


def compiled_step(config: GANConfig, generator, discriminator):
    """``make_gan_step`` jitted, donating its state: one per losses and optimisers, whatever else
    of ``config`` (run folder, steps, seed, ...) differs."""
    return _jitted_step(dataclasses.replace(config, run_dir="", steps=1, seed=0, save_every=1, keep=1,
                                            progress=False, log_every=1), generator, discriminator)


@functools.lru_cache(maxsize=4)
def _jitted_step(config: GANConfig, generator, discriminator):
    return jax.jit(make_gan_step(config, generator, discriminator), donate_argnums=0)


def _inputs(batch: dict) -> tuple[jax.Array, jax.Array]:
    """(image float32 in [0, 1], semantic int32) of a batch."""
    image = np.asarray(batch["image"])
    image = image.astype(np.float32) / 255.0 if image.dtype == np.uint8 else image.astype(np.float32)
    return jnp.asarray(image), jnp.asarray(batch["label"], jnp.int32)


def train_gan(config: GANConfig, generator, discriminator, batches: Iterable[dict]) -> GANState:
    """Run (or resume) ``config.steps`` GAN steps; see the module docstring. Raises
    NonFiniteLossError when a loss or gradient stops being finite (the last good checkpoint stays)."""
    os.makedirs(config.run_dir, exist_ok=True)
    source = iter(batches)
    first = next(source)
    check_batch(first, generator.num_classes, UNKNOWN)
    generator.check(np.asarray(first["label"]))
    step_fn = compiled_step(config, generator, discriminator)
    log = RunLog(config.run_dir)

    def log_steps(logged: list, images_per_s: float) -> dict:
        for step, metrics in logged:
            metrics = {name: float(value) for name, value in metrics.items()}
            metrics["images_per_s"] = images_per_s
            log.scalars(step, {f"train/{name}": value for name, value in metrics.items()})
        return {"g": f"{metrics['g_loss']:.3f}", "d": f"{metrics['d_loss']:.3f}", "l1": f"{metrics['l1']:.3f}"}

    try:  # the losses of the steps since the last read are read together: one log line per step, the window's throughput
        return run_loop(lambda state, batch: step_fn(state, *_inputs(batch)),
                        lambda: init_gan_state(config, generator, discriminator, first), source, config.steps,
                        first=first, checkpoints=Checkpoints(config.run_dir, config.save_every, config.keep),
                        log_every=config.log_every, on_log=log_steps, examples=lambda batch: len(batch["image"]),
                        progress=progress_bar(config.progress))
    finally:
        log.close()


def trained_generator(config: GANConfig, generator, discriminator, batch: dict) -> dict:
    """The generator's ``{"params", "batch_stats"}`` from the finished run in ``config.run_dir``,
    read-only (``batch``: shapes only). ValueError naming the folder when there is no checkpoint,
    it is damaged, or the run stopped before ``config.steps``."""
    template = jax.eval_shape(lambda: init_gan_state(config, generator, discriminator, batch))
    return jax.device_get(restore_run(config.run_dir, template, config.steps).generator_variables)
