"""Evaluation drivers: a network over a dataset -> pooled anomaly metrics and segmentation mIoU.

``predictor(model, variables)`` builds the jitted forward pass once. ``anomaly_results``
scores every batch with each method and pools the pixels of the whole dataset, as the
benchmarks do (docs/papers/anomaly-metrics.md#pooling). ``segmentation_results`` sums confusion matrices.
"""
from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from typing import Callable, Iterable, Iterator

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.app.outputs import within
from jaxanom.app.scoring import inputs_of, score_all
from jaxanom.cudam.score import upsample_attention
from jaxanom.method_registry import check_finite
from jaxanom.metrics import anomaly_metrics, pr_curve, restrict_to_roi, roc_curve
from jaxanom.io import jsonable
from jaxanom.metrics.evaluator import (Components, PixelAnomaly, Segmentation, SmiycPixels, get_evaluator,
                                       run_evaluators)
from jaxanom.train.step import model_input
from jaxanom.errors import InputError

CONVENTIONS = ("exact", "smiyc")  # jaxanom's exact curves; the official SegmentMeIfYouCan kit's bins


def predictor(model, variables) -> Callable[[np.ndarray], dict]:
    """A jitted ``images (B, H, W, 3) (uint8 RGB, or float normalised) -> {"logits" (B, H, W, C), "attention_up" (B, H, W)?}``.

    uint8 images are normalised as ``model`` wants them (``jaxanom.train.step.model_input``).
    The attention map (if the model has one) is upsampled bilinearly to the image size (Eqs. 4, 10);
    ``"attention_positions"`` (a Python int) is then the h * w of the map before upsampling: a
    shape, known without reading the device (taken once per input shape from ``jax.eval_shape``).
    """

    def apply(variables, images):
        return model.apply(variables, model_input(images, model), train=False)

    @jax.jit
    def forward(variables, images):
        out = apply(variables, images)
        result = {"logits": out["logits"].astype(jnp.float32)}
        if "attention" in out:
            result["attention_up"] = upsample_attention(out["attention"], images.shape[1:3])
        return result

    positions: dict = {}

    def call(images):
        images = jnp.asarray(images)
        result = forward(variables, images)
        if "attention_up" in result:
            key = (images.shape, images.dtype)
            if key not in positions:
                attention = jax.eval_shape(apply, variables, images)["attention"]
                positions[key] = int(attention.shape[1] * attention.shape[2])
            result["attention_positions"] = positions[key]
        return result

    return call


def predictions(predict: Callable, batches: Iterable[dict]) -> Iterator[dict]:
    """Each batch with the network's outputs added (``"logits"``, maybe ``"attention_up"``), in
    order. A batch is yielded once the next one is dispatched, so the device computes the next
    batch while the caller reads this one back (two batches' outputs are held at a time)."""
    pending = None
    for batch in batches:
        dispatched = {**batch, **predict(batch["image"])}
        if pending is not None:
            yield pending
        pending = dispatched
    if pending is not None:
        yield pending


def protocol_predictions(predict: Callable, source, protocol, skipped: list | None = None,
                         check_size: Callable | None = None) -> Iterator[dict]:
    """One-frame batches of ``source`` (a frame reader) as ``protocol`` (``jaxanom.protocols``)
    counts them, with the network's outputs added: each frame resized to the protocol's size, the
    frames it skips left out (their names appended to ``skipped``) before the network runs.
    ``check_size((h, w), name)`` (``app.predict.size_check``) refuses a size before the network runs on it."""
    from jaxanom.data.pipeline import evaluation_batches

    for batch in evaluation_batches(protocol.source(source), batch_size=1):
        if protocol.counts(batch["label"]):
            if check_size is not None:
                check_size(batch["image"].shape[1:3], str(batch.get("name", ["?"])[0]))
            yield {**batch, **predict(batch["image"])}
        elif skipped is not None:
            skipped.extend(str(name) for name in batch.get("name", ["?"]))


def class_statistics(predict: Callable, batches: Iterable[dict], drop_void: bool = False):
    """SML class statistics (Eqs. 3-4, a ``sml.ClassStats``) of the network's logits over ``batches``;
    ``drop_void``: of the logits without the void output (as a protocol that drops it scores them)."""
    from jaxanom import sml
    from jaxanom.app.scoring import without_channel

    return sml.fit_stats(without_channel(out["logits"]) if drop_void else out["logits"]
                         for out in predictions(predict, batches))


# what --convention smiyc moves from a method's metrics to its "exact": the exact curve's numbers and labels
EXACT_KEYS = ("ap", "auroc", "fpr_at_tpr", "best_f1", "best_f1_threshold", "ap_convention", "fpr_convention",
              "ap_conventions", "fpr_conventions")


def anomaly_results(outputs: Iterable[dict], method_names, *, stats=None, options: dict | None = None,
                    mode: str = "exact", fpr_convention: str = "first", ap_convention: str = "step",
                    keep_curves: bool = False, track: str | None = None,
                    spill_dir: str | Path | None = None, convention: str = "exact",
                    drop_void: bool = False, evaluators: tuple[str, ...] = ()) -> tuple[dict, dict]:
    """Pooled metrics per method over batches ``{"logits", "label", "image"?, "name"?,
    "attention_up"?, "attention_positions"?, "roi"?, "mmf_maps"?}``.

    ``method_names``: registered methods (``jaxanom.method_registry``); ``stats``: SML
    ``(mean, std)``; ``options``: ``{method: {option: value}}`` (e.g. ``{"cudam": {"cudam_sigma":
    2e4}}``; absent or None: the method's default, which may depend on the batch, as CuDAM's
    paper-equivalent sigma does). ``metrics[name]["options"]`` lists, for a method with
    options, the distinct values each took, in the order met. Every method's metrics hold
    ``ap_conventions`` and ``fpr_conventions`` (all conventions' values).
    ``track`` (``"anomaly"`` / ``"obstacle"``): also SegmentMeIfYouCan's component metrics at
    the pooled best-F1 threshold (``metrics[name]["components"]``) and, per frame, the pixel
    metrics (None where the frame lacks a class) and component metrics
    (``metrics[name]["frames"]``); score maps wait in a temporary folder between the passes,
    ``.jaxanom-maps-*.tmp`` in ``spill_dir`` (default: the system's temporary folder): the CLI
    spills into its claimed ``--out``, whose take-over removes what a killed run left.
    Returns ``(metrics[name], curves[name])``; ``curves[name] = {"roc": (fpr, tpr), "pr":
    (recall, precision), "scores": [(H, W) per frame], "labels": [(H, W) per frame, outside the
    ROI 255]}`` when ``keep_curves`` (it keeps every score on the host: small sets only).
    ``mode="binned"`` is not offered here because score ranges differ per method.
    ``convention="smiyc"``: AP / AUROC / FPR / best F1 and the component threshold and mask as
    the official SegmentMeIfYouCan kit computes them (``jaxanom.metrics.smiyc``), labelled
    ``"convention": "smiyc"``; the exact values move to ``metrics[name]["exact"]`` with the
    labels of the conventions that made them (``ap_convention``, ``fpr_convention`` and every
    convention's value, ``ap_conventions`` / ``fpr_conventions``), so each number carries its own. Batches may carry finished score maps
    ``"maps": {name: (B, H, W)}`` instead of ``"logits"`` (``saved_map_batches``). ``drop_void``:
    the methods but ``void`` score the logits without a void channel (``app.scoring.score_all``).
    A method's scores that are not finite on non-void pixels are refused naming it
    (``method_registry.check_finite``, one count per map). ``evaluators``: names of registered
    evaluators (``metrics.evaluator.get_evaluator``, a plug-in's included) also fed each method's
    scores in the same pass, their metrics as JSON values in ``metrics[name]["evaluators"][evaluator]``
    (the other numbers are the same with or without them); a value one refuses (ValueError) is an
    InputError naming ``evaluators``, the evaluator and the method.
    InputError naming ``path`` when the frames pool no anomaly or no normal pixel (each frame's
    reason said), and naming ``methods`` when ``convention="smiyc"`` meets a score outside float16.
    """
    import itertools
    import tempfile

    if convention not in CONVENTIONS:
        raise ValueError(f"convention: expected one of {CONVENTIONS}, got {convention!r}")
    named = {kind: get_evaluator(kind) for kind in evaluators}  # an unknown name refused before any frame
    spill = (tempfile.TemporaryDirectory(prefix=".jaxanom-maps-", suffix=".tmp", dir=spill_dir)
             if track is not None else None)
    try:
        batches = _scored_batches(outputs, method_names, stats, options, drop_void, convention,
                                  None if spill is None else Path(spill.name))
        first = list(itertools.islice(batches, 1))  # its methods name the evaluators
        methods = list(first[0]["scores"]) if first else []
        folds = {"frames": _Frames(), "options": _OptionsUsed()}  # first: no class, no metric computed
        for name in methods:
            folds["pixels", name] = PixelAnomaly(name, mode, fpr_convention, ap_convention, conventions=True)
            if convention == "smiyc":
                folds["kit", name] = SmiycPixels(name)
            if keep_curves:
                folds["curves", name] = _Curves(name)
            if spill is not None:
                folds["frame_pixels", name] = _FramePixels(name, fpr_convention, ap_convention)
            for kind, evaluator in named.items():
                folds["named", name, kind] = _Named(kind, name, evaluator.make(name))
        results = run_evaluators(folds, itertools.chain(first, batches))
    except BaseException:  # a refused frame mid-way leaves no spilled maps in --out
        if spill is not None:
            spill.cleanup()
        raise
    metrics = {name: results["pixels", name] for name in methods}
    for name, values in results["options"].items():
        if values:
            metrics[name]["options"] = values
    if convention == "smiyc":  # the kit's numbers on top, "convention": "smiyc"; the exact ones
        for name, values in metrics.items():  # move with the conventions that made them
            values["exact"] = {key: values.pop(key) for key in EXACT_KEYS}
            values.update(results["kit", name])
    for name, values in metrics.items():
        for kind in named:
            values.setdefault("evaluators", {})[kind] = jsonable(results["named", name, kind])
    if spill is not None:
        with spill:
            for name, values in metrics.items():
                components = Components(name, values["best_f1_threshold"], track, convention)
                values["components"], values["frames"] = _component_pass(Path(spill.name), components,
                                                                         results["frames"]["names"],
                                                                         results["frame_pixels", name])
    return metrics, {name: results["curves", name] for name in methods if keep_curves}


def _scored_batches(outputs: Iterable[dict], method_names, stats, options, drop_void: bool, convention: str,
                    spill: Path | None) -> Iterator[dict]:
    """Each batch of ``outputs`` scored (``anomaly_results``' arguments) and checked: ``{"scores":
    {method: (B, H, W)}, "label" (the ROI applied), "name" (Nones if none), "options": used}``;
    with ``spill``, each frame's label and scores saved there as ``label_<i>.npy`` and
    ``<method>_<i>.npy``, i counting frames."""
    frames = 0
    for batch in outputs:
        if "maps" in batch:  # finished score maps (saved_map_batches)
            batch_scores, used = batch["maps"], {}
        else:
            batch_scores, used = score_all(method_names, inputs_of(batch, stats), options, drop_void=drop_void)
        labels = np.asarray(batch["label"])
        if "roi" in batch:  # evaluate inside the region of interest only (MMF: the road)
            labels = restrict_to_roi(labels, batch["roi"])
        names = batch.get("name", [None] * len(labels))
        where = f" of frame {', '.join(map(str, names))}" if "name" in batch else ""
        for name, score in batch_scores.items():  # a count per map, read once the next batch is dispatched
            check_finite(name, score, labels, where)
        for name, score in batch_scores.items() if convention == "smiyc" else ():
            _check_kit_range(name, score, labels, names)
        if spill is not None:
            for index, label in enumerate(labels):
                np.save(spill / f"label_{frames + index}.npy", label)
            for name, score in batch_scores.items():
                for index, one in enumerate(np.asarray(score)):
                    np.save(within(spill, spill / f"{name}_{frames + index}.npy"), one)
        yield {"scores": batch_scores, "label": labels, "name": names, "options": used}
        frames += len(labels)


class _Framewise:
    """``init`` / ``merge`` of an evaluator whose state is a tuple of per-frame entries, in frame order."""

    def init(self) -> tuple:
        return ()

    def merge(self, a: tuple, b: tuple) -> tuple:
        return a + b


class _Frames(_Framewise):
    """Each frame's name and anomaly / normal pixel counts; ``finalize``: ``{"names": [each frame's
    name, else its index]}``, or InputError naming ``path`` (``_check_both_classes``) unless the
    frames pool both classes."""

    def update(self, state: tuple, batch: dict) -> tuple:
        return state + tuple((name, int((label == 1).sum()), int((label == 0).sum()))
                             for name, label in zip(batch["name"], batch["label"]))

    def finalize(self, state: tuple) -> dict:
        _check_both_classes(list(state))
        return {"names": [str(name) if name is not None else str(index) for index, (name, _, _) in enumerate(state)]}


@dataclasses.dataclass(frozen=True)
class _Curves(_Framewise):
    """``method``'s pooled ROC and PR curves, with every frame's score map and label kept on the host
    (small sets only): ``{"roc": (fpr, tpr), "pr": (recall, precision), "scores", "labels"}``."""

    method: str

    def update(self, state: tuple, batch: dict) -> tuple:
        return state + tuple(zip(np.asarray(batch["scores"][self.method]), batch["label"]))

    def finalize(self, state: tuple) -> dict:
        maps, truths = (list(x) for x in zip(*state))
        scores, labels = (np.concatenate([x.ravel() for x in xs]) for xs in (maps, truths))
        fpr, tpr, _ = roc_curve(scores, labels)
        precision, recall, _ = pr_curve(scores, labels)
        return {"roc": (fpr, tpr), "pr": (recall, precision), "scores": maps, "labels": truths}


@dataclasses.dataclass(frozen=True)
class _FramePixels(_Framewise):
    """Every frame's AP / AUROC / FPR of ``method``'s scores (None where the frame lacks a class), in order."""

    method: str
    fpr_convention: str
    ap_convention: str

    def update(self, state: tuple, batch: dict) -> tuple:
        return state + tuple(_frame_pixel_metrics(one, label, self.fpr_convention, self.ap_convention)
                             for one, label in zip(np.asarray(batch["scores"][self.method]), batch["label"]))

    def finalize(self, state: tuple) -> list:
        return list(state)


@dataclasses.dataclass(frozen=True)
class _Named:
    """The evaluator ``kind`` of ``method``'s scores (``evaluator``), whose ValueError (a value it
    refuses, e.g. ``smiyc_pixels``' score beyond float16) is an InputError naming ``evaluators``,
    ``kind``, ``method`` and, in ``update``, the batch's frames."""

    kind: str
    method: str
    evaluator: object

    @contextlib.contextmanager
    def _refusals(self, where: str = ""):
        try:
            yield
        except ValueError as error:
            raise InputError("evaluators", f": {self.kind} refused {self.method}'s scores{where}: {error}") from None

    def init(self):
        return self.evaluator.init()

    def update(self, state, batch: dict):
        with self._refusals(f" of frame {', '.join(map(str, batch['name']))}"):
            return self.evaluator.update(state, batch)

    def merge(self, a, b):
        return self.evaluator.merge(a, b)

    def finalize(self, state):
        with self._refusals():
            return self.evaluator.finalize(state)


class _OptionsUsed:
    """``{method: {option: [the distinct values it took, in the order met]}}`` of batches' ``"options"``
    (``score_all``'s ``used``)."""

    def init(self) -> dict:
        return {}

    def update(self, state: dict, batch: dict) -> dict:
        for name, values in batch["options"].items():
            for key, value in values.items():
                if value not in (seen := state.setdefault(name, {}).setdefault(key, [])):
                    seen.append(value)
        return state

    def merge(self, a: dict, b: dict) -> dict:
        merged = {name: {key: list(seen) for key, seen in values.items()} for name, values in a.items()}
        for name, values in b.items():
            for key, seen in values.items():
                into = merged.setdefault(name, {}).setdefault(key, [])
                into.extend(value for value in seen if value not in into)
        return merged

    def finalize(self, state: dict) -> dict:
        return state


def _check_both_classes(counted: list[tuple]) -> None:
    """InputError naming ``path`` unless the frames ``(name, anomaly pixels, normal pixels)`` pool
    pixels of both classes (AP, AUROC and FPR@95 need both), with each frame's reason."""
    if not counted:
        raise InputError("path", ": no frame to score")
    if sum(c[1] for c in counted) and sum(c[2] for c in counted):
        return
    missing = "anomaly" if not sum(c[1] for c in counted) else "normal (non-anomaly, non-void)"

    def reason(positives, negatives):
        return "all void" if not positives + negatives else "no anomaly pixel" if not positives else "no normal pixel"

    shown = [f"{'?' if name is None else name}: {reason(p, n)}" for name, p, n in counted[:5]]
    more = f", and {len(counted) - 5} more" if len(counted) > 5 else ""
    raise InputError("path", f": no {missing} pixel in any of the {len(counted)} frames scored ({'; '.join(shown)}"
                     f"{more}); AP, AUROC and FPR@95 are undefined without both classes")


def _check_kit_range(method: str, scores, labels: np.ndarray, names) -> None:
    """InputError naming ``methods`` where a non-void score of ``method`` (``scores`` (B, H, W),
    ``labels`` (B, H, W), frames ``names``) has no float16 value. The official SegmentMeIfYouCan
    kit stores every map as float16 (``anomaly_p.astype(np.float16)`` in its ``save_output``),
    which turns such a score into +-inf and its bin edges into infinite or NaN ones
    (docs/decisions/smiyc-convention.md): no number of the kit's exists to reproduce."""
    from jaxanom.metrics.smiyc import FLOAT16_MAX

    for one, label, name in zip(np.asarray(scores), labels, names):
        values = one[label != 255]
        bad = values[~(np.abs(values) <= FLOAT16_MAX)]  # NaN included
        if bad.size:
            raise InputError("methods", f": {method}'s scores of frame {name} reach {bad[0]:g}, outside float16's "
                             f"range (|score| <= {FLOAT16_MAX:g}); the official SegmentMeIfYouCan kit stores maps "
                             "as float16, where such scores become inf and its bins undefined; use {convention} exact",
                             mentions=("convention",))


def _frame_pixel_metrics(score, label, fpr_convention: str, ap_convention: str) -> dict | None:
    """AP / AUROC / FPR of one frame, or None when it has no anomaly or no normal pixel."""
    present = np.isin((0, 1), label)
    if not present.all():
        return None
    return anomaly_metrics(score, label, fpr_convention=fpr_convention, ap_convention=ap_convention)


def _component_pass(folder: Path, components: Components, names: list[str], pixels: list[dict | None]):
    """``(pooled, per_frame)``: the ``components`` evaluator of the method's maps spilled into
    ``folder``, one frame at a time; each frame's entry holds its ``name`` and its ``pixels`` metrics."""
    method, pooled, per_frame = components.method, components.init(), []
    for index, (name, frame_pixels) in enumerate(zip(names, pixels)):
        one = {"scores": {method: np.load(folder / f"{method}_{index}.npy")[None]},
               "label": np.load(folder / f"label_{index}.npy")[None]}
        state = components.update(components.init(), one)
        pooled = components.merge(pooled, state)
        per_frame.append({"name": name, **(frame_pixels or {"ap": None}),
                          "components": _jsonable_components(components.finalize(state))})
    return ({"threshold": components.threshold, "track": components.track,
             **_jsonable_components(components.finalize(pooled))}, per_frame)


def _jsonable_components(summary: dict) -> dict:
    """A ``component_summary`` for metrics.json: lists, NaN as None, without the per-component arrays."""
    out = {}
    for key, value in summary.items():
        if key in ("tp", "fn", "fp"):
            out[key] = [int(v) for v in value]
        elif isinstance(value, int):
            out[key] = value
        elif key not in ("siou", "ppv"):
            values = [None if np.isnan(v) else float(v) for v in np.ravel(value)]
            out[key] = values if np.ndim(value) else values[0]
    return out


def segmentation_results(outputs: Iterable[dict], num_classes: int, ignore: int = 255) -> dict:
    """mIoU, pixel accuracy and per-class IoU over batches ``{"logits", "label"}`` (trainIds)."""
    scores = run_evaluators({"segmentation": Segmentation(num_classes, ignore)}, outputs)["segmentation"]
    return {"miou": scores["miou"], "pixel_accuracy": scores["pixel_accuracy"], "per_class_iou": scores["iou"].tolist()}


def dataset_reader(dataset: str, path: str, *, base: str | None = None, frames: int | None = None,
                   depth: str | None = None, size: dict | None = None):
    """The reader of ``dataset`` (a key of ``jaxanom evaluate``'s ``DATASETS``) at ``path``; ``base``:
    the base images of the Fishyscapes sets; ``frames``: count of synthetic frames; ``depth``:
    SMIYC disparity folder; ``size``: keyword arguments of the synthetic scenes (MMF: its size,
    disparity and road ROI)."""
    from jaxanom import data

    if dataset == "synthetic":
        return data.SyntheticScenes(path, frames, seed=1, **(size or {}))
    if dataset == "road-anomaly":
        return data.RoadAnomaly(path)
    if dataset == "smiyc":
        return data.SegmentMeIfYouCan(path, depth_root=depth)
    if dataset == "lost-and-found":
        return data.LostAndFound(path)
    if not base:
        raise InputError("base", f": the {dataset} dataset needs the root of its base images")
    reader = data.FishyscapesLostAndFound if dataset == "fishyscapes-laf" else data.FishyscapesStatic
    return reader(path, base)


# the SegmentMeIfYouCan dataset folders (``app.predict.SMIYC_DATASETS``) whose track is theirs alone;
# the Lost and Found ones are scored with either track's rules (Fishyscapes: anomaly; the kit: obstacle)
MAP_TRACKS = {"AnomalyTrack-all": "anomaly", "ObstacleTrack-all": "obstacle", "RoadObstacleWeather-v1": "obstacle",
              "RoadObstacleExtra-v1": "obstacle", "SmallObstacleDataset-train": "obstacle",
              "SmallObstacleDataset-val": "obstacle", "SmallObstacleDataset-test": "obstacle"}


def saved_map_batches(folder: str | Path, source, methods: list[str] | None = None,
                      track: str | None = None) -> tuple[list[str], Iterator[dict]]:
    """``(methods, batches)``: the score maps ``jaxanom predict --format smiyc`` wrote into ``folder``
    (``anomaly_p/<method>/<dataset>/<frame>.hdf5``, float16 HDF5 dataset ``value``: the official
    SegmentMeIfYouCan submission tree) as one-frame batches ``{"maps": {method: (1, H, W)},
    "label", "name"}`` for ``anomaly_results``, in the order of ``source`` (a ``FrameReader``
    whose frame names are the files' stems). ``methods``: default every method folder. Every file is
    looked for before the first is read: FileNotFoundError naming what is missing. ``track``
    (``"anomaly"`` / ``"obstacle"``: the component rules they will be scored with): InputError
    naming ``maps`` and ``track`` when a dataset folder is the other track's (``MAP_TRACKS``)."""
    from jaxanom.app.predict import output_file

    root = Path(folder) / "anomaly_p"
    if not root.is_dir():
        raise FileNotFoundError(f"no anomaly_p folder in {folder} (written by jaxanom predict --format smiyc)")
    methods = list(methods) if methods else sorted(p.name for p in root.iterdir() if p.is_dir())
    if not methods:
        raise FileNotFoundError(f"no method folder in {root}")
    names = [str(frame[0]) for frame in source.frames]  # a FrameReader's (name, image, label) without decoding
    files = {}
    for method in methods:
        datasets = sorted(p.name for p in (root / method).iterdir() if p.is_dir()) if (root / method).is_dir() else []
        if len(datasets) != 1:
            raise FileNotFoundError(f"expected one dataset folder in {root / method}, found {datasets or 'none'}")
        if track in ("anomaly", "obstacle") and MAP_TRACKS.get(datasets[0], track) != track:
            raise InputError("maps", f": {root / method / datasets[0]} holds the {MAP_TRACKS[datasets[0]]} track's "
                             f"maps, which {{track}} {track} would score with the {track} track's component rules; "
                             f"pass {{track}} {MAP_TRACKS[datasets[0]]} (or none)", mentions=("track",))
        files[method] = [output_file(Path(folder), name, method, "smiyc", datasets[0]) for name in names]
        missing = [f.name for f in files[method] if not f.is_file()]
        if missing:
            raise FileNotFoundError(f"{len(missing)} of {len(names)} frames have no map in "
                                    f"{root / method / datasets[0]}, e.g. {', '.join(missing[:3])}")

    def batches():
        import h5py

        for index in range(len(source)):
            frame = source[index]
            maps = {}
            for method in methods:
                with h5py.File(files[method][index], "r") as f:
                    maps[method] = np.squeeze(f["value"][()])[None]
                if maps[method].shape[1:] != frame["label"].shape:
                    raise InputError("maps", f": {files[method][index]} is {maps[method].shape[1:]}, its label "
                                     f"{frame['label'].shape}")
            yield {"maps": maps, "label": frame["label"][None], "name": [frame["name"]]}

    return methods, batches()
