"""Resynthesis from the predicted semantic map (docs/papers/mmf.md#resynthesis): class means, or a trained SPADE generator.

``ClassMeanSynthesizer`` is the CPU stand-in for MMF's cGAN synthesizer: each class is painted in
its mean training colour, so, like a GAN's output, the resynthesis keeps the layout of the
semantic map and has no appearance detail. ``fit`` runs on the host (NumPy); ``synthesize`` is a
pure-JAX gather with a ``jit(vmap)`` batch twin. ``SPADESynthesizer`` holds a ``SPADEGenerator``
trained by ``mmf.gan_train`` (Table 4's "lighter" synthesizer). Both expose ``arrays`` and
``synthesize_batch``; ``resynthesize`` is either one inside a caller's own ``jit``.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any, Iterable

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_integer, check_rank, values_checked
from jaxanom.models.spade_generator import SPADEGenerator

UNKNOWN = 255


def paint_class_means(means: jax.Array, semantic: jax.Array) -> jax.Array:
    """means (C+1, 3), semantic (...) int -> (..., 3): row c for class c, row C for anything else."""
    classes = means.shape[0] - 1
    return means[jnp.where((semantic >= 0) & (semantic < classes), semantic, classes)]


_synthesize_jit = jax.jit(paint_class_means)
_synthesize_batch = jax.jit(jax.vmap(paint_class_means, in_axes=(None, 0)))


@dataclasses.dataclass(frozen=True)
class ClassMeanSynthesizer:
    """``means`` (C+1, 3) float32 RGB in [0, 1]: row c the mean colour of class c, row C the
    mean over all pixels (painted where the semantic map says 255, unknown)."""

    means: np.ndarray

    @property
    def arrays(self) -> np.ndarray:
        """What ``paint_class_means`` reads: the table ``means``."""
        return self.means

    @classmethod
    def fit(cls, frames: Iterable[dict], num_classes: int, semantic_key: str = "semantic") -> "ClassMeanSynthesizer":
        """Mean colour per class over frames ``{"image" (H, W, 3) uint8, semantic_key (H, W) int}``.

        Pixels labelled 255 count towards the global mean only; a class with no pixel gets it.
        """
        sums, counts = np.zeros((num_classes + 1, 3)), np.zeros(num_classes + 1)
        for frame in frames:
            image = np.asarray(frame["image"])
            semantic = np.asarray(frame[semantic_key]).astype(np.int64)
            if image.shape != semantic.shape + (3,):
                raise ValueError(f"frame['image'] must be (H, W, 3) with (H, W) = {semantic_key} {semantic.shape}, "
                                 f"got {image.shape}")
            rgb = image.reshape(-1, 3) / 255.0 if image.dtype == np.uint8 else image.reshape(-1, 3).astype(np.float64)
            known = (semantic >= 0) & (semantic < num_classes)
            if not np.all(known | (semantic == UNKNOWN)):
                raise ValueError(f"frame[{semantic_key!r}] must hold classes in [0, {num_classes}) or 255")
            index = np.where(known, semantic, num_classes).ravel()
            counts += np.bincount(index, minlength=num_classes + 1)
            for channel in range(3):
                sums[:, channel] += np.bincount(index, rgb[:, channel], minlength=num_classes + 1)
        if counts.sum() == 0:
            raise ValueError("frames must contain at least one pixel, got none")
        overall = sums.sum(0) / counts.sum()
        means = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], overall)
        means[num_classes] = overall
        return cls(means.astype(np.float32))

    def _checked(self, semantic, rank: int, layout: str) -> jax.Array:
        check_rank("semantic", semantic, rank, layout)
        check_integer("semantic", semantic)
        if values_checked(semantic):
            values = np.asarray(semantic)
            bad = ~(((values >= 0) & (values < len(self.means) - 1)) | (values == UNKNOWN))
            if bad.any():
                raise ValueError(f"semantic must hold classes in [0, {len(self.means) - 1}) or 255, "
                                 f"got {values[bad][:5].tolist()}")
        return jnp.asarray(semantic, jnp.int32)

    def synthesize(self, semantic) -> jax.Array:
        """semantic (H, W) int (classes, 255 unknown) -> image r (H, W, 3) float32 in [0, 1]."""
        return _synthesize_jit(jnp.asarray(self.means), self._checked(semantic, 2, "(H, W)"))

    def synthesize_batch(self, semantic) -> jax.Array:
        """``synthesize`` over a batch: (B, H, W) -> (B, H, W, 3)."""
        return _synthesize_batch(jnp.asarray(self.means), self._checked(semantic, 3, "(B, H, W)"))


@dataclasses.dataclass(frozen=True, eq=False)
class SPADESynthesizer:
    """A trained ``SPADEGenerator`` ``model`` with its ``variables`` ({"params", "batch_stats"})."""

    model: SPADEGenerator
    variables: Any

    @property
    def arrays(self) -> Any:
        """What ``model.apply`` reads: the generator's variables."""
        return self.variables

    def synthesize_batch(self, semantic) -> jax.Array:
        """semantic (B, H, W) int (classes, 255 unknown) -> r (B, H, W, 3) float32 in [0, 1]
        (BatchNorm with its running statistics)."""
        self.model.check(semantic)
        return _generate(self.model, self.variables, jnp.asarray(semantic, jnp.int32))


def resynthesize(generator: SPADEGenerator | None, arrays, semantic: jax.Array) -> jax.Array:
    """semantic (B, H, W) -> r (B, H, W, 3) in [0, 1] for a synthesizer's ``arrays``: class means
    when ``generator`` is None, else ``generator`` with its variables. No checks (for jit)."""
    if generator is None:
        return paint_class_means(jnp.asarray(arrays), semantic)
    return generator.apply(arrays, semantic)["image"]


@functools.partial(jax.jit, static_argnums=0)
def _generate(model: SPADEGenerator, variables, semantic: jax.Array) -> jax.Array:
    return resynthesize(model, variables, semantic)
