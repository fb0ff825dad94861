"""Anomaly maps of image files: the application behind ``jaxanom predict``.

``predict_images(paths, out, scorer)`` streams the images through a network (any run that
``jaxanom evaluate --run`` loads): each image is decoded, resized to the network's working size
(bilinear; or kept at its own size), scored on the device with each method
(``jaxanom.method_registry``) at the working size, alone (a batch of one, so that its maps do not
depend on the frames around it), and each map is resized back (bilinear) to the image's native
size and written in every requested format:

- ``npy``:   ``<out>/npy/<method>/<frame>.npy``, float16 (H, W);
- ``png``:   ``<out>/png/<method>/<frame>.png``, the image and the map over it, with a colour bar;
- ``smiyc``: ``<out>/anomaly_p/<method>/<dataset>/<frame>.hdf5``, float16 (H, W) in the HDF5
  dataset ``value`` (gzip level 9): SegmentMeIfYouCan's submission tree. The benchmark's code
  (github SegmentMeIfYouCan/road-anomaly-benchmark, ``road_anomaly_benchmark/evaluation.py``
  and ``datasets/dataset_io.py``) stores ``anomaly_p.astype(float16)`` at
  ``anomaly_p/{method_name}/{dset_name}/{fid}.hdf5`` through ``ChannelLoaderHDF5(var_name=
  "value", compression=9)``; ``fid`` is the image's file stem and ``dset_name`` e.g.
  ``AnomalyTrack-all``, ``ObstacleTrack-all``, ``LostAndFound-test`` (``datasets/tracks.py``).

``<frame>`` is the image's file name (as given, not a symlink's target) without its extension.
Every file is written under a temporary name beside it and renamed, so a killed run leaves
complete files only, and a rerun skips the frames whose files all exist (and removes the
temporary files a kill left). ``settings.json`` in ``out`` records the settings and the
fingerprints of the methods' code and options, the network and the statistics the maps were
made with (``settings_record``); a rerun that would make other maps is refused
(``check_resumable``). Every file written or removed is proven inside ``out``
(``app.outputs.within``).

With ``threads`` > 1 the host work runs beside the device's: a pool decodes the next frames
ahead, in order, and a pool of writers resizes, checks and writes each frame's maps under
temporary names, which the calling thread renames in frame order. Frames are published in the
same order as with one thread and the files hold the same bytes; the first failure (a corrupt
image, a map float16 cannot hold, the device out of memory) leaves every frame before it
written and none after it.
"""
from __future__ import annotations

import contextlib
import dataclasses
import glob
import io
import json
import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np

from jaxanom.app.outputs import inside, within
from jaxanom.config_codec import encode
from jaxanom.errors import InputError

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".webp")
FORMATS = ("npy", "png", "smiyc")
SETTINGS_FILE = "settings.json"
# The dataset folders SegmentMeIfYouCan's kit reads maps from: each split of a track reads its
# full set's folder (AnomalyTrack-validation reads AnomalyTrack-all's maps, ObstacleTrack-night
# ObstacleTrack-all's, the Fishyscapes subsets LostAndFound-*'s), so no other name is ever read.
SMIYC_DATASETS = ("AnomalyTrack-all", "ObstacleTrack-all", "LostAndFound-test", "LostAndFound-train",
                  "RoadObstacleWeather-v1", "RoadObstacleExtra-v1", "SmallObstacleDataset-train",
                  "SmallObstacleDataset-val", "SmallObstacleDataset-test")
FLOAT16_MAX = float(np.finfo(np.float16).max)
# the maps predict writes (``output_file``), found in a folder without knowing its settings
MAP_PATTERNS = ("npy/*/*.npy", "png/*/*.png", "anomaly_p/*/*/*.hdf5")
READ_FROM = "read_from"  # the record's paths of the run and statistics: where, not what (not compared)
METHOD_CODE = "method_code"  # the record's fingerprint and options of each method (compared last)
# settings that change how fast the maps are made, not what they hold: left out of the record
SPEED_ONLY = ("batch_size", "threads")
# settings of earlier versions that are options of their methods now (``--slic-step``, ``--cudam-sigma``),
# recorded with every other option under METHOD_CODE: an earlier record's are not compared again
RETIRED = ("slic_step", "cudam_sigma")


def default_threads() -> int:
    """Host threads of ``predict`` by default: half the CPUs this process may use, at most 8.

    The other half is left to the thread that dispatches to the device and to XLA, which on a
    CPU backend computes on the same cores (so a 2-core machine gets 1: the serial loop); 8 decode
    and write 1024x2048 frames faster than an accelerator scores them, and more only add memory."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(8, cpus // 2))


class DeviceOutOfMemory(Exception):
    """The accelerator could not allocate a frame's computation (XLA's RESOURCE_EXHAUSTED)."""


@dataclasses.dataclass(frozen=True)
class PredictSettings:
    """What ``predict_images`` computes and writes.

    ``methods``: registered methods (``jaxanom.method_registry``; not the MMF pipeline rows);
    ``formats``: from ``FORMATS``; ``size``: the working (H, W) the network sees, or None for
    each image's own size; ``batch_size``: frames dispatched to the device before the first of
    them is read back (each is computed alone, so the maps do not depend on it); ``dataset``: the SMIYC
    dataset name (format ``smiyc``); ``unit_interval``: (center, scale) to write
    ``metrics.smiyc.to_unit_interval`` of every map instead of the score (None: the score);
    ``threads``: host threads decoding frames ahead and as many writing maps behind (1: all in
    the calling thread; None: ``default_threads()``); the maps do not depend on it.
    """

    methods: tuple[str, ...]
    formats: tuple[str, ...] = ("npy",)
    size: tuple[int, int] | None = None
    batch_size: int = 1
    dataset: str | None = None
    unit_interval: tuple[float, float] | None = None
    threads: int | None = None

    def __post_init__(self):
        from jaxanom.app.scoring import INPUTS, check

        check(self.methods, set(INPUTS) - {"mmf_maps"})  # all a run can give predict (no MMF pipeline)
        if len(set(self.methods)) != len(self.methods) or len(set(self.formats)) != len(self.formats):
            raise InputError("methods", ", {formats}: expected no repeats, got "
                             f"{list(self.methods)}, {list(self.formats)}", mentions=("formats",))
        if not self.formats or any(f not in FORMATS for f in self.formats):
            raise InputError("formats", f": expected names from {FORMATS}, got {list(self.formats)}")
        if self.size is not None and (len(self.size) != 2 or min(self.size) < 1):
            raise InputError("size", f": expected (height, width) >= 1, got {self.size}")
        if self.batch_size < 1:
            raise InputError("batch_size", f": expected >= 1, got {self.batch_size}")
        if self.threads is not None and self.threads < 1:
            raise InputError("threads", f": expected >= 1 (or None: {default_threads()} on this machine), "
                             f"got {self.threads}")
        if "smiyc" in self.formats and self.dataset not in SMIYC_DATASETS:
            raise InputError("dataset", ": the smiyc format needs a dataset folder the benchmark's kit reads, one of "
                             f"{', '.join(SMIYC_DATASETS)} (a split such as AnomalyTrack-validation reads its full "
                             f"set's), got {self.dataset!r}")
        if self.unit_interval is not None and not (len(self.unit_interval) == 2 and np.isfinite(self.unit_interval).all()
                                                   and self.unit_interval[1] > 0):
            raise InputError("unit_interval", f": expected (center, scale > 0), finite, got {self.unit_interval}")


def list_images(inputs: Sequence[str], out: Path | None = None) -> tuple[list[Path], int]:
    """Image files named by ``inputs``: files, folders (their image files, not recursive) or
    glob patterns (``**`` recursive); sorted per input, without repeats, as given (a symlink is
    not replaced by its target, so two links to one file are two frames). Those under ``out``
    (``predict``'s own outputs, matched by a recursive glob over a tree that holds them) are
    left out. Returns ``(images, how many were left out)``.

    FileNotFoundError for an input that names nothing; InputError (a ValueError) when every image
    lies under ``out``, for a named file without an image extension, or two images with the same
    file stem (their outputs would collide).
    """
    found: list[Path] = []
    for text in inputs:
        path = Path(text)
        if path.is_dir():
            matches = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
        elif path.is_file():
            if path.suffix.lower() not in IMAGE_EXTENSIONS:
                raise InputError("images", f": expected files ending in {IMAGE_EXTENSIONS}, got {text}")
            matches = [path]
        elif glob.has_magic(text):
            matches = sorted(Path(p) for p in glob.glob(text, recursive=True)
                             if Path(p).is_file() and Path(p).suffix.lower() in IMAGE_EXTENSIONS)
        else:
            matches = []
        if not matches:
            raise FileNotFoundError(f"images: {text} names no image file ({', '.join(IMAGE_EXTENSIONS)})")
        found.extend(matches)
    unique: dict[str, Path] = {}
    for path in found:  # one path given twice (a file and its folder, "x.png" and "./x.png") is one frame
        unique.setdefault(os.path.abspath(path), path)
    kept = [p for p in unique.values() if out is None or not _under(p, out)]
    if not kept:
        raise InputError("images", f": every image given lies inside {{out}} {out}, where predict writes",
                         mentions=("out",))
    stems: dict[str, Path] = {}
    for path in kept:
        if path.stem in stems:
            raise InputError("images", f": {stems[path.stem]} and {path} share the frame name {path.stem!r}; "
                             "their outputs would overwrite each other")
        stems[path.stem] = path
    return kept, len(unique) - len(kept)


def _under(path: Path, folder: Path) -> bool:
    """``path`` lies in ``folder``, as written or once symlinks are resolved."""
    written = Path(os.path.abspath(path))
    return Path(os.path.abspath(folder)) in written.parents or inside(path, folder)


def output_file(out: Path, frame: str, method: str, fmt: str, dataset: str | None) -> Path:
    """The file of one frame, method and format (module docstring)."""
    if fmt == "smiyc":
        return out / "anomaly_p" / method / dataset / f"{frame}.hdf5"
    return out / fmt / method / f"{frame}.{fmt}"


def output_files(out: Path, frame: str, settings: PredictSettings) -> list[Path]:
    """Every file ``predict_images`` writes for ``frame``."""
    return [output_file(out, frame, m, f, settings.dataset) for m in settings.methods for f in settings.formats]


def fingerprint(tree) -> str:
    """SHA-256 (hex) of a pytree of arrays and strings: every leaf's path, dtype, shape and bytes."""
    import hashlib

    import jax

    digest = hashlib.sha256()
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        value = np.ascontiguousarray(leaf)
        digest.update(f"{jax.tree_util.keystr(path)} {value.dtype.str} {value.shape}\n".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def settings_record(settings: PredictSettings, *, network: str, statistics: str | None, read_from: dict,
                    options: dict | None = None) -> dict:
    """What decides the maps: ``settings`` (but ``SPEED_ONLY``, which do not change them), each
    method's code and options (``METHOD_CODE``: ``method_registry.implementation`` and every
    option, its default or ``options``' (``{method: {option: value}}``), before a frame resolves
    it), the ``fingerprint`` of the network (its experiment
    and the variables restored) and of the statistics (mean and std; None without), and, for
    the reader only, where they were read."""
    from jaxanom.method_registry import get, implementation

    record = encode(settings)
    for name in SPEED_ONLY:
        del record[name]
    code = {name: {"code": implementation(name), "options": get(name).unresolved((options or {}).get(name))}
            for name in settings.methods}
    return {**record, METHOD_CODE: json.loads(json.dumps(code, default=repr)), "network": network,
            "statistics": statistics, READ_FROM: read_from}


def existing_maps(out: Path) -> list[Path]:
    """The map files in ``out`` (any method, format and dataset; not unfinished temporaries)."""
    return [p for pattern in MAP_PATTERNS for p in out.glob(pattern) if p.is_file()]


def _earlier_record(out: Path) -> dict | None:
    """``out``'s settings.json, or None when it is absent or not a JSON object."""
    try:
        earlier = json.loads((out / SETTINGS_FILE).read_text())
    except (OSError, ValueError):
        return None
    return earlier if isinstance(earlier, dict) else None


def _difference(earlier: dict | None, record: dict) -> str | None:
    """How maps of the ``earlier`` record differ from ``record``'s, in words; None when they do not."""
    if earlier is None:
        return f"and no readable {SETTINGS_FILE} saying how they were made"
    if "network" not in earlier:
        return "made by an older jaxanom, which did not record their network and statistics"
    retired = {key for key in RETIRED if key not in record}  # compared as options, in METHOD_CODE
    for key in sorted((set(earlier) | set(record)) - {READ_FROM} - retired, key=lambda k: (k == METHOD_CODE, k)):
        before, now = earlier.get(key), record.get(key)
        if before == now:
            continue
        if key == METHOD_CODE:
            return _method_difference(before, now)
        if key == "network":
            return f"made with another network (weights or experiment) than {{run}} {record[READ_FROM]['run']} holds now"
        if key == "statistics" and before and now:
            return f"made with other statistics than {{stats}} {record[READ_FROM]['stats']} holds now"
        if key == "statistics":
            return "made with statistics, now without" if before else \
                f"made without statistics, now with {{stats}} {record[READ_FROM]['stats']}"
        return f"made with {key}={before!r}, now {key}={now!r}"
    return None


def _method_difference(before: dict | None, now: dict) -> str:
    """How the ``METHOD_CODE`` entries of two records with the same methods differ, in words."""
    if not isinstance(before, dict):
        return "made by an older jaxanom, which did not record its methods' code and options"
    for name, entry in now.items():
        earlier = before.get(name) or {}
        if earlier.get("code") != entry["code"]:
            return (f"of method {name!r} made by other code (its module's source changed, or another plug-in "
                    "registers that name)")
        if earlier.get("options") != entry["options"]:
            return f"of method {name!r} made with options {earlier.get('options')}, now {entry['options']}"
    return f"made with {METHOD_CODE}={before!r}"


def check_resumable(out: Path, record: dict) -> bool:
    """Whether a run of ``record`` may go on in ``out`` (without ``--overwrite``): True when its
    ``settings.json`` is ``record``'s (the frames already there may be skipped), or when it holds
    one but no map (a run stopped before its first map); False without one; ValueError naming
    the difference when its maps were made with other settings, network or statistics."""
    if not (out / SETTINGS_FILE).is_file():
        return False
    difference = _difference(_earlier_record(out), record)
    if difference is not None and existing_maps(out):
        raise InputError("out", f"{out}: holds maps {difference}; choose another folder, "
                         "or pass {overwrite} to recompute them", mentions=("overwrite", "run", "stats"))
    return True


def remove_other_maps(out: Path, record: dict, settings: PredictSettings) -> int:
    """Before a run of ``record`` that recomputes every frame it is given (``--overwrite``): unless
    ``out``'s ``settings.json`` is ``record``'s, delete the maps in the folders this run writes
    (of frames it may not be given: a later resume would keep them as its own). Returns how many."""
    if _difference(_earlier_record(out), record) is None:
        return 0
    removed = 0
    for method in settings.methods:
        for fmt in settings.formats:
            pattern = output_file(out, "*", method, fmt, settings.dataset)
            for path in pattern.parent.glob(pattern.name):
                if within(out, path).is_file():
                    path.unlink()
                    removed += 1
    return removed


def _decode(path: Path, size) -> dict:
    """A decoded frame: ``{"name", "image" (native RGB uint8), "input" (at the working size)}``."""
    import cv2

    from jaxanom.data.image_io import read_rgb

    image = read_rgb(path)  # ValueError naming a corrupt file
    resized = image if size is None or image.shape[:2] == tuple(size) else \
        cv2.resize(image, (size[1], size[0]), interpolation=cv2.INTER_LINEAR)
    return {"name": path.stem, "image": image, "input": resized}


@contextlib.contextmanager
def _frames(paths: Sequence[Path], size, threads: int) -> Iterator[Iterator[dict]]:
    """The decoded frames of ``paths`` in order, each decoding's exception raised at its frame;
    with ``threads`` > 1 decoded by a pool, at most ``2 * threads`` ahead of the reader (a
    1024x2048 frame holds 6 MB and its working-size input). Leaving the block cancels the rest."""
    if threads == 1:
        yield (_decode(path, size) for path in paths)
        return
    with ThreadPoolExecutor(threads, thread_name_prefix="predict-decode") as pool:
        ahead: deque = deque()

        def decoded() -> Iterator[dict]:
            upcoming = iter(paths)
            while True:
                while len(ahead) < 2 * threads and (path := next(upcoming, None)) is not None:
                    ahead.append(pool.submit(_decode, path, size))
                if not ahead:
                    return
                yield ahead.popleft().result()

        try:
            yield decoded()
        finally:
            for future in ahead:
                future.cancel()


def _batches(frames: Iterable[dict], batch_size: int) -> Iterator[list[dict]]:
    """Consecutive frames, at most ``batch_size`` at a time (the last batch as many as remain).
    When a frame cannot be decoded, the frames before it are yielded first, then its ValueError raised."""
    batch: list[dict] = []
    frames = iter(frames)
    while True:
        try:
            frame = next(frames)
        except StopIteration:
            break
        except ValueError:
            if batch:
                yield batch
            raise
        batch.append(frame)
        if len(batch) == batch_size:
            yield batch
            batch = []
    if batch:
        yield batch


class Scorer:
    """Network + methods on each frame of a batch, dispatched asynchronously (``__call__``), read back later.

    Each frame is computed alone, through one compiled program per working size: batched
    convolutions may round a frame differently with other frames beside it (an ulp on some
    CPUs), so a frame's maps would depend on its batch-mates, and a resumed run on its batches.
    ``options``: the methods' options, ``{method: {option: value}}`` (None: their defaults).
    """

    def __init__(self, predict: Callable, settings: PredictSettings, stats=None, check_size=None, options=None):
        self.predict, self.settings, self.stats, self.check_size = predict, settings, stats, check_size
        self.options = options or {}  # {method: {option: value}}
        self._checked: set = set()

    def __call__(self, batch: list[dict]) -> list[dict]:
        """Device arrays ``{method: (1, h, w)}`` of each frame of ``batch``."""
        return [self._score(frame) for frame in batch]

    def _score(self, frame: dict) -> dict:
        from jaxanom.app.scoring import inputs_of, score_all

        images = frame["input"][None]
        shape = images.shape[1:3]
        if self.check_size is not None and shape not in self._checked:
            self.check_size(shape, frame["name"])
            self._checked.add(shape)
        out = self.predict(images)
        maps = score_all(self.settings.methods, inputs_of({**out, "image": images}, self.stats),
                         self.options)[0]
        if self.settings.unit_interval is None:
            return maps
        from jaxanom.metrics.smiyc import to_unit_interval

        return {name: to_unit_interval(score, *self.settings.unit_interval) for name, score in maps.items()}


def native_map(score: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A float32 map resized (bilinear, half-pixel centres) to ``shape`` (H, W)."""
    import cv2

    score = np.asarray(score, np.float32)
    if score.shape == tuple(shape):
        return score
    return cv2.resize(score, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)


def write_frame(out: Path, frame: dict, maps: dict, settings: PredictSettings) -> None:
    """Every output file of one frame; ``maps[method]`` (H, W) at the image's native size. When a
    method's map cannot be written (not finite in float16), the files of the methods before it are."""
    staged, error = stage_frame(out, frame, maps, settings)
    _publish(staged)
    if error is not None:
        raise error


def stage_frame(out: Path, frame: dict, maps: dict, settings: PredictSettings) -> tuple[list, Exception | None]:
    """``write_frame``'s files under temporary names beside them: ``([(temporary, file), ...], error)``
    in the order ``write_frame`` writes them; ``error``: the exception that stopped staging (the
    files before it are staged, as ``write_frame`` would have written them), or None."""
    from jaxanom.io import png_bytes, write_synced, write_temporary
    from jaxanom.method_registry import check_finite

    staged: list[tuple[str, Path]] = []
    try:
        for method, score in maps.items():
            check_finite(method, score, where=f" of {frame['name']}")
            half = None
            if {"npy", "smiyc"} & set(settings.formats):
                if np.abs(score).max(initial=0.0) > FLOAT16_MAX:
                    raise InputError("methods", f": method {method!r}: scores of {frame['name']} are not finite in "
                                     f"float16 (|score| <= {FLOAT16_MAX:g}); the npy and smiyc formats store float16")
                half = score.astype(np.float16)
            for fmt in settings.formats:
                path = within(out, output_file(out, frame["name"], method, fmt, settings.dataset))
                if fmt == "npy":
                    buffer = io.BytesIO()
                    np.save(buffer, half)
                    data = buffer.getvalue()
                elif fmt == "smiyc":
                    staged.append((write_temporary(path, lambda tmp: _write_hdf5(tmp, half)), path))
                    continue
                else:
                    from jaxanom.viz import Panel, render_panels

                    panels = [Panel(frame["name"], frame["image"]),
                              Panel(f"{method} over the image", score, base=frame["image"],
                                    label=f"{method} (higher = more anomalous)")]
                    data = png_bytes(render_panels(panels, columns=2, min_width=512, max_width=1024))
                staged.append((write_temporary(path, lambda tmp: write_synced(tmp, data)), path))
    except Exception as error:  # noqa: BLE001  handed to the thread that publishes, which raises it
        return staged, error
    return staged, None


def _publish(staged: list) -> None:
    """Rename staged files into place, in order (the temporaries of any not renamed are removed)."""
    try:
        for tmp, path in staged:
            os.replace(tmp, path)
    finally:
        _discard(staged)


def _discard(staged: list) -> None:
    for tmp, _ in staged:
        Path(tmp).unlink(missing_ok=True)


def _write_hdf5(path: str, value: np.ndarray) -> None:
    import h5py

    with h5py.File(path, "w") as f:
        f.create_dataset("value", data=value, compression=9)  # gzip level 9, as the benchmark writes


class _Writes:
    """Frames' files, staged (``_native_staged``) by ``threads`` writer threads, at most
    ``2 * threads`` frames behind, and published by the calling thread in the order submitted;
    with one thread, each at once. A frame that failed is published as far as it got, then its
    exception raised; ``failed`` says so, and the frames submitted after it are never published.
    Leaving the block by another exception publishes what was submitted before it, as one thread
    would have written it, then stops the writers."""

    def __init__(self, out: Path, settings: PredictSettings, threads: int, published: Callable[[], None]):
        self.out, self.settings, self.threads, self.published = out, settings, threads, published
        self.failed = False
        self._pool = ThreadPoolExecutor(threads, thread_name_prefix="predict-write") if threads > 1 else None
        self._staging: deque = deque()

    def submit(self, frame: dict, maps: dict) -> None:
        """Write ``frame``'s ``maps`` ((h, w) host arrays at the working size)."""
        if self._pool is None:
            self._publish(_native_staged(self.out, frame, maps, self.settings))
            return
        self._staging.append(self._pool.submit(_native_staged, self.out, frame, maps, self.settings))
        while len(self._staging) > 2 * self.threads:
            self._publish(self._staging.popleft().result())

    def flush(self) -> None:
        """Publish every frame submitted (raising the first failure)."""
        while self._staging:
            self._publish(self._staging.popleft().result())

    def _publish(self, result: tuple[list, Exception | None]) -> None:
        staged, error = result
        if self.failed:  # a frame before it failed: as if never written
            _discard(staged)
            return
        self.failed = error is not None
        _publish(staged)
        if error is not None:
            raise error
        self.published()

    def __enter__(self) -> "_Writes":
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is None:
            return
        self._pool.shutdown(wait=True)
        while self._staging:
            with contextlib.suppress(Exception):  # the exception leaving the block is the one to report
                self._publish(self._staging.popleft().result())


def _native_staged(out: Path, frame: dict, maps: dict, settings: PredictSettings) -> tuple[list, Exception | None]:
    """``stage_frame`` of the ``maps`` resized to the frame's native size."""
    shape = frame["image"].shape[:2]
    try:
        native = {name: native_map(score, shape) for name, score in maps.items()}
    except Exception as error:  # noqa: BLE001  raised by the thread that publishes
        return [], error
    return stage_frame(out, frame, native, settings)


def predict_images(paths: Sequence[Path], out: Path, scorer: Scorer, *, progress: bool = True,
                   redo: bool = False) -> dict:
    """Score ``paths`` into ``out`` (see the module docstring); frames whose files all exist are
    skipped (unless ``redo``), and unfinished temporary files of a killed run (``.<file>.*.tmp``)
    are removed: the caller must hold ``out`` alone (the CLI claims it). Returns ``{"frames",
    "written", "skipped"}``. A corrupt image raises ValueError naming it, and a device
    out-of-memory ``DeviceOutOfMemory`` naming the frame, after the frames before are written."""
    from jax.errors import JaxRuntimeError
    from tqdm import tqdm

    settings = scorer.settings
    threads = default_threads() if settings.threads is None else settings.threads
    for root in {"npy": out / "npy", "png": out / "png", "smiyc": out / "anomaly_p"}.values():
        for stale in root.rglob(".*.tmp") if root.is_dir() else ():  # a killed run's unfinished files
            within(out, stale).unlink(missing_ok=True)
    todo = [p for p in paths if redo or not all(f.is_file() for f in output_files(out, p.stem, settings))]
    bar = tqdm(total=len(todo), unit="image", desc="predict", disable=not progress)
    pending = at = None
    written = 0

    def published():
        nonlocal written
        written += 1
        bar.update(1)

    def finish(batch, scores):
        for frame, frame_scores in zip(batch, scores):
            writes.submit(frame, {name: np.asarray(value)[0] for name, value in frame_scores.items()})

    with contextlib.ExitStack() as stack:
        stack.callback(bar.close)
        frames = stack.enter_context(_frames(todo, settings.size, threads))
        writes = stack.enter_context(_Writes(out, settings, threads, published))
        try:
            for batch in _batches(frames, settings.batch_size):
                at = batch
                scores = scorer(batch)  # dispatched: the device works while the next batch is decoded
                done, pending = pending, (batch, scores)
                if done is not None:
                    at = done[0]
                    finish(*done)
            done, pending = pending, None
            if done is not None:
                at = done[0]
                finish(*done)
            writes.flush()
        except (ValueError, JaxRuntimeError) as error:
            out_of_memory = isinstance(error, JaxRuntimeError) and "RESOURCE_EXHAUSTED" in str(error)
            if pending is not None and not writes.failed and (out_of_memory or isinstance(error, ValueError)):
                # the batch before the failure (e.g. a corrupt image in the next one) was computed: keep it
                with contextlib.suppress(JaxRuntimeError):  # unless the device failed it too
                    finish(*pending)
            writes.flush()
            if out_of_memory:
                names = at[0]["name"] if len(at) == 1 else f"{at[0]['name']} .. {at[-1]['name']}"
                height, width = max((f["input"].shape[:2] for f in at), key=lambda shape: shape[0] * shape[1])
                raise DeviceOutOfMemory(f"the device ran out of memory scoring {names} ({len(at)} in flight, "
                                        f"working size up to {height}x{width}); {written} frames written") from None
            raise
    return {"frames": len(paths), "written": len(todo), "skipped": len(paths) - len(todo)}


def logits_shape(model, variables, size: tuple[int, int]) -> tuple[int, ...]:
    """The shape of ``model``'s logits for one (h, w) image (``jax.eval_shape``: no compute;
    any float input will do for shapes, so the network's own normalisation is not needed)."""
    import jax
    import jax.numpy as jnp

    spec = jax.ShapeDtypeStruct((1, *size, 3), jnp.float32)
    return tuple(jax.eval_shape(lambda v, x: model.apply(v, x, train=False), variables, spec)["logits"].shape)


def size_check(model, variables, argument: str = "size",
               advice: str = "; choose a working size it takes ({size})") -> Callable[[tuple[int, int], str], None]:
    """``check((h, w), frame)``: InputError naming ``argument`` (followed by ``advice``) unless
    ``model`` takes (1, h, w, 3) images and returns logits of that size (shapes only; each size
    is checked once)."""
    checked: set = set()

    def check(shape: tuple[int, int], frame: str) -> None:
        shape = tuple(int(n) for n in shape)
        if shape in checked:
            return
        try:
            logits = logits_shape(model, variables, shape)
        except Exception as error:  # flax / XLA shape errors of many types: one line naming the size
            reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise InputError(argument, f": the network does not run on {shape[0]}x{shape[1]} images ({frame}): "
                             f"{reason}{advice}", mentions=("size",)) from None
        if logits[1:3] != shape:
            raise InputError(argument, f": the network's logits are {logits[1:3]} for {shape[0]}x{shape[1]} images "
                             f"({frame}); expected the input's size")
        checked.add(shape)

    return check


__all__ = ["DeviceOutOfMemory", "FORMATS", "PredictSettings", "Scorer", "check_resumable", "default_threads",
           "existing_maps",
           "fingerprint", "inside", "list_images", "native_map", "logits_shape", "output_file", "output_files",
           "predict_images", "remove_other_maps", "settings_record", "size_check", "stage_frame", "write_frame"]
