"""One contract for every dataset metric: an evaluator folds batches into a state, then reads metrics off it.

Shaped like ``sml.ClassStats`` (``stats_init`` / ``stats_update`` / ``stats_merge`` /
``stats_finalize``), an evaluator has ``init() -> state``, ``update(state, batch) -> state``,
``merge(a, b) -> state`` (the frames of both, ``a``'s first) and ``finalize(state) -> dict``.
One pass over a dataset and parts of it merged afterwards give the same metrics, so the state of
one frame is what a bootstrap over frames resamples, and parts evaluated apart can be pooled.
``run_evaluators`` feeds the same batches to several evaluators.

Batches are dicts with ``"label"`` (B, H, W). The anomaly evaluators read
``batch["scores"][method]`` (B, H, W) floats (higher = more anomalous) against labels 0 normal,
1 anomaly, 255 void (restrict them to a region of interest before: ``restrict_to_roi``); the
segmentation evaluator reads ``batch["logits"]`` (B, H, W, C) (its argmax) against class labels;
``ConfusionSum`` reads ``batch["confusion"]``, a (K, K) confusion matrix computed where the network ran.
``update`` may change the state in place (host accumulators do): use the state it returns.
``merge`` leaves its inputs as they were.

Evaluators of one method's scores are plug-ins by name like scoring methods (``EVALUATORS``, a
``jaxanom.registry.Registry``): a ``NamedEvaluator`` makes the evaluator of a method's scores;
jaxanom's (``pixel``, ``smiyc_pixels``) are registered here (this module is in
``jaxanom.builtins``), a module of one's own registers its own with ``register``, loaded by
``--plugin MODULE`` or an installed package's entry-point group ``jaxanom.evaluators``, and
``jaxanom score --evaluators NAME`` and ``jaxanom evaluate --evaluators NAME`` run them by name.
"""
from __future__ import annotations

import dataclasses
import sys
from typing import Any, Callable, Iterable, Mapping, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom import builtins, registry
from jaxanom.errors import InputError
from jaxanom.metrics.accumulator import AnomalyMetricAccumulator
from jaxanom.metrics.components import component_summary, frame_components
from jaxanom.metrics.segmentation import confusion_matrix, frame_confusion_matrices, confusion_scores
from jaxanom.metrics.smiyc import binned_metrics, frame_bins, smiyc_frame_components


class Evaluator(Protocol):
    """What every evaluator offers (module docstring)."""

    def init(self) -> Any: ...

    def update(self, state: Any, batch: dict) -> Any: ...

    def merge(self, a: Any, b: Any) -> Any: ...

    def finalize(self, state: Any) -> dict: ...


def run_evaluators(evaluators: Mapping[str, Evaluator], batches: Iterable[dict]) -> dict[str, dict]:
    """``{name: finalized metrics}`` of every evaluator fed every batch once, finalized in order
    (an evaluator that raises in ``finalize`` stops the ones after it)."""
    states = {name: evaluator.init() for name, evaluator in evaluators.items()}
    for batch in batches:
        states = {name: evaluator.update(states[name], batch) for name, evaluator in evaluators.items()}
    # each state is freed once finalized: the exact accumulators hold every distinct score
    return {name: evaluator.finalize(states.pop(name)) for name, evaluator in evaluators.items()}


def update_keyed(evaluated: dict, key, make: Callable[[], Evaluator], batch: dict) -> None:
    """Feed ``batch`` to ``evaluated[key] = (evaluator, state)``, the evaluator made by ``make()``
    where ``key`` is new (e.g. one evaluator per scoring method, the methods met in the batches)."""
    evaluator, state = evaluated[key] if key in evaluated else (make(), None)
    evaluated[key] = evaluator, evaluator.update(evaluator.init() if state is None else state, batch)


@dataclasses.dataclass(frozen=True)
class NamedEvaluator:
    """An evaluator of one method's scores, by name: ``make(method) -> Evaluator`` (e.g. an
    evaluator class whose one required field is the method, as ``PixelAnomaly``); ``description``:
    one line, shown by ``--help``."""

    name: str
    make: Callable[[str], Evaluator]
    description: str

    def __post_init__(self):
        if not callable(self.make):
            raise ValueError(f"make of evaluator {self.name!r}: expected a function (method name) -> evaluator")
        if not isinstance(self.description, str) or not self.description.strip() or "\n" in self.description.strip():
            raise ValueError(f"description of evaluator {self.name!r}: expected one line, got {self.description!r}")


ENTRY_POINTS = "jaxanom.evaluators"
EVALUATORS: registry.Registry[NamedEvaluator] = registry.Registry("evaluator", ENTRY_POINTS, lambda: builtins.MODULES)


def register(evaluator: NamedEvaluator) -> NamedEvaluator:
    """Add ``evaluator`` under its name (``registry.NAME_RULE``), registered by the calling module;
    ValueError in one line when the name is not a name or another evaluator has it. Returns it."""
    if not isinstance(evaluator, NamedEvaluator):
        raise ValueError(f"evaluator: expected a jaxanom.metrics.evaluator.NamedEvaluator, got "
                         f"{type(evaluator).__name__}")
    return EVALUATORS.add(evaluator.name, evaluator, sys._getframe(1).f_globals.get("__name__", "?"))


def evaluator_names() -> tuple[str, ...]:
    """Every registered evaluator's name: jaxanom's own first, then installed plug-ins', then loaded modules'."""
    return EVALUATORS.names()


def get_evaluator(name: str) -> NamedEvaluator:
    """The evaluator called ``name``; InputError naming ``evaluators`` and the known names (and an
    entry point that failed to load, which might have provided it) otherwise."""
    found = EVALUATORS.find(name)
    if found is None:
        raise InputError("evaluators", f": expected names from {', '.join(EVALUATORS.names())}, got {name!r} (a "
                         f"plug-in's evaluator: load its module, e.g. with --plugin MODULE){EVALUATORS.broken_note()}")
    return found


@dataclasses.dataclass(frozen=True)
class PixelAnomaly:
    """Pooled pixel AP, AUROC, FPR at ``tpr`` (``anomaly_metrics``' dict) of ``method``'s scores;
    the state is an ``AnomalyMetricAccumulator`` of ``mode`` (``"binned"``: give ``score_range``)."""

    method: str
    mode: str = "exact"
    fpr_convention: str = "first"
    ap_convention: str = "step"
    tpr: float = 0.95
    conventions: bool = False
    score_range: tuple[float, float] | None = None

    def init(self) -> AnomalyMetricAccumulator:
        return AnomalyMetricAccumulator(self.mode, score_range=self.score_range)

    def update(self, state: AnomalyMetricAccumulator, batch: dict) -> AnomalyMetricAccumulator:
        state.update(batch["scores"][self.method], batch["label"])
        return state

    def merge(self, a: AnomalyMetricAccumulator, b: AnomalyMetricAccumulator) -> AnomalyMetricAccumulator:
        return a.merge(b)

    def finalize(self, state: AnomalyMetricAccumulator) -> dict:
        return state.compute(fpr_convention=self.fpr_convention, ap_convention=self.ap_convention, tpr=self.tpr,
                             conventions=self.conventions)


@dataclasses.dataclass(frozen=True)
class SmiycPixels:
    """The official SegmentMeIfYouCan kit's binned pixel metrics (``smiyc.binned_metrics``) of
    ``method``'s scores; the state is the tuple of every frame's ``FrameBins``, in order (the kit
    breaks ties between frames by their order)."""

    method: str

    def init(self) -> tuple:
        return ()

    def update(self, state: tuple, batch: dict) -> tuple:
        return state + tuple(map(frame_bins, np.asarray(batch["scores"][self.method]), np.asarray(batch["label"])))

    def merge(self, a: tuple, b: tuple) -> tuple:
        return a + b

    def finalize(self, state: tuple) -> dict:
        return binned_metrics(state)


@dataclasses.dataclass(frozen=True)
class Components:
    """SegmentMeIfYouCan component metrics (``component_summary``: sIoU, PPV, F1 over 11
    thresholds) of ``method``'s mask at ``threshold`` under ``track``'s size rules, pooled over
    frames. ``convention``: ``"exact"`` (mask score >= threshold) or ``"smiyc"`` (the kit's
    float16 score > threshold). The state is the tuple of every frame's (sIoU, PPV) arrays.
    The threshold is usually a dataset's pooled best-F1 one: a ``PixelAnomaly`` pass comes first."""

    method: str
    threshold: float
    track: str = "anomaly"
    convention: str = "exact"

    def __post_init__(self):
        if self.convention not in ("exact", "smiyc"):
            raise ValueError(f"convention: expected 'exact' or 'smiyc', got {self.convention!r}")

    def init(self) -> tuple:
        return ()

    def update(self, state: tuple, batch: dict) -> tuple:
        rule = smiyc_frame_components if self.convention == "smiyc" else frame_components
        return state + tuple(rule(score, label, self.threshold, track=self.track)
                             for score, label in zip(np.asarray(batch["scores"][self.method]),
                                                     np.asarray(batch["label"])))

    def merge(self, a: tuple, b: tuple) -> tuple:
        return a + b

    def finalize(self, state: tuple) -> dict:
        empty = np.zeros(0, np.float64)
        return component_summary(np.concatenate([empty, *(siou for siou, _ in state)]),
                                 np.concatenate([empty, *(ppv for _, ppv in state)]))


@dataclasses.dataclass(frozen=True)
class Segmentation:
    """mIoU, pixel accuracy and the other ``confusion_scores`` of the logits' argmax against
    class labels (``ignore`` skipped); the state is the int64 (K, K) confusion matrix (rows:
    label), K = ``num_classes``; ``scored``: score the first ``scored`` classes only (the others
    are outputs that are always wrong, e.g. a void channel)."""

    num_classes: int
    ignore: int = 255
    scored: int | None = None

    def init(self) -> np.ndarray:
        return np.zeros((self.num_classes, self.num_classes), np.int64)

    def update(self, state: np.ndarray, batch: dict) -> np.ndarray:
        matrix = confusion_matrix(jnp.argmax(batch["logits"], axis=-1), batch["label"], self.num_classes, self.ignore)
        return state + np.asarray(matrix, np.int64)

    def frame_states(self, batch: dict) -> np.ndarray:
        """(B, K, K) int64: the state of each frame of ``batch`` alone (their sum is ``update``'s)."""
        return np.asarray(frame_confusion_matrices(jnp.argmax(batch["logits"], axis=-1), batch["label"],
                                                   self.num_classes, self.ignore), np.int64)

    def merge(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return a + b

    def finalize(self, state: np.ndarray) -> dict:
        return confusion_scores(state, self.scored)


@dataclasses.dataclass(frozen=True)
class ConfusionSum:
    """``Segmentation``'s metrics of the (K, K) confusion matrices the batches carry as
    ``batch["confusion"]`` (e.g. a jitted eval step's, on the device), summed where they are and
    read back once, in ``finalize``. The state is None before the first batch, then the sum."""

    scored: int | None = None

    def init(self) -> None:
        return None

    def update(self, state, batch: dict):
        return batch["confusion"] if state is None else state + batch["confusion"]

    def merge(self, a, b):
        return b if a is None else a if b is None else a + b

    def finalize(self, state) -> dict:
        if state is None:
            raise ValueError("batches: expected at least one batch, got none")
        return confusion_scores(np.asarray(jax.device_get(state)), self.scored)


register(NamedEvaluator("pixel", PixelAnomaly, "pooled pixel AP, AUROC, FPR95 and best F1, exact "
                        "(anomaly_metrics)"))
register(NamedEvaluator("smiyc_pixels", SmiycPixels, "the official SegmentMeIfYouCan kit's binned pixel AP, AUROC, "
                        "FPR95 and best F1"))
