"""The training input pipeline on grain: deterministic, sharded per process, resumable.

source -> shuffle (seed, reshuffled every epoch) -> augment (one RNG per record, from the seed and
the record's position) -> batch -> this process's batches -> iterator. Every batch is a pure
function of ``(seed, step, process)``, so a run restarted from ``iterator.get_state()`` (a small
dict to store next to the checkpoint) sees exactly the batches it would have seen.

Batches are dicts of stacked NumPy arrays: ``"image"`` (B, h, w, 3) uint8, ``"label"`` (B, h, w)
uint8 (and ``"depth"`` when the source has it); normalise on the device with
``jaxanom.data.transforms.normalize``. With P processes, process p takes global batches
p, p + P, p + 2P, ...: its ``batch_size`` is the per-process batch size.
``evaluation_batches`` batches a source in order, unchanged, for scoring and metrics.
"""
from __future__ import annotations

from typing import Any, Sequence

import grain

from jaxanom.data.transforms import Augment

_PIXEL_KEYS = ("image", "label", "depth")


def _unaugmented(record: dict[str, Any]) -> dict[str, Any]:
    """The pixel maps and name of a record (a named function, so that grain can pickle it)."""
    return {key: record[key] for key in (*_PIXEL_KEYS, "name") if key in record}


def _processes(process_index: int | None, process_count: int | None) -> tuple[int, int]:
    if process_index is None or process_count is None:
        import jax

        process_index, process_count = jax.process_index(), jax.process_count()
    if not 0 <= process_index < process_count:
        raise ValueError(f"process_index: expected 0 <= index < process_count={process_count}, got {process_index}")
    return process_index, process_count


def training_batches(
    source: Sequence[dict[str, Any]],
    *,
    batch_size: int,
    augment: Augment,
    seed: int = 0,
    num_epochs: int | None = None,
    process_index: int | None = None,
    process_count: int | None = None,
    num_threads: int = 0,
) -> grain.DatasetIterator:
    """An iterator of augmented training batches; ``get_state`` / ``set_state`` resume it.

    ``source``: random access (``len`` and ``[i]``), e.g. a reader or ``SyntheticScenes``.
    ``num_epochs=None`` repeats forever. ``process_index`` / ``process_count`` default to
    ``jax.process_index()`` / ``jax.process_count()``. ``num_threads > 0`` reads ahead with
    that many threads (same batches, same order); 0 reads in the calling thread.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
    if len(source) < batch_size:
        raise ValueError(f"source: expected at least batch_size={batch_size} records, got {len(source)}")
    process_index, process_count = _processes(process_index, process_count)
    dataset = (
        grain.MapDataset.source(source)
        .shuffle(seed=seed)
        .repeat(num_epochs)
        .random_map(augment, seed=seed)
        .batch(batch_size, drop_remainder=True)
    )
    # Every process gets the same number of batches, so collective steps never wait on one.
    usable = len(dataset) if num_epochs is None else len(dataset) - len(dataset) % process_count
    dataset = dataset[process_index:usable:process_count]
    # grain's default read-ahead (16 threads, 500 records) would hog a small machine: ask explicitly.
    options = grain.ReadOptions(num_threads=num_threads, prefetch_buffer_size=2 * num_threads)
    return iter(dataset.to_iter_dataset(options))


def evaluation_batches(
    source: Sequence[dict[str, Any]],
    *,
    batch_size: int,
    process_index: int | None = None,
    process_count: int | None = None,
) -> grain.DatasetIterator:
    """Batches of the source's frames in order, unchanged (no shuffle, no augmentation).

    Frames of one batch must share their size. The last batch may be smaller; process p gets
    batches p, p + P, ... (so counts may differ by one across processes). ``"name"`` is kept.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
    process_index, process_count = _processes(process_index, process_count)
    dataset = (
        grain.MapDataset.source(source)
        .map(_unaugmented)
        .batch(batch_size)
    )
    dataset = dataset[process_index::process_count]
    return iter(dataset.to_iter_dataset(grain.ReadOptions(num_threads=0, prefetch_buffer_size=0)))
