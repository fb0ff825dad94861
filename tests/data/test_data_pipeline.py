"""The grain pipeline: reproducible by seed, resumable from its state, sharded across processes."""
import numpy as np
import pytest

from jaxanom.data.pipeline import evaluation_batches, training_batches
from jaxanom.data.synthetic import SyntheticScenes
from jaxanom.data.transforms import Augment


class _Numbered:
    """Record i is a 4x4 frame whose label is filled with i (a record's identity survives batching)."""

    def __init__(self, n):
        self.n = n

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        return {"image": np.full((4, 4, 3), i, np.uint8), "label": np.full((4, 4), i, np.uint8), "name": str(i)}


IDENTITY = Augment(crop_hw=(4, 4), scale_range=(1.0, 1.0), flip_prob=0.0, jitter=0.0)
SCENES = SyntheticScenes("train", 6, seed=1, height=24, width=40)
CROP = Augment(crop_hw=(16, 16))


def _ids(batch):
    return batch["label"][:, 0, 0].tolist()


def _take(iterator, k):
    return [next(iterator) for _ in range(k)]


def _equal(a, b):
    return a.keys() == b.keys() and all(np.array_equal(a[key], b[key]) for key in a)


def test_batches_are_reproducible_by_seed_and_differ_across_seeds():
    make = lambda seed: training_batches(SCENES, batch_size=2, augment=CROP, seed=seed,  # noqa: E731
                                         process_index=0, process_count=1)
    a, b, c = _take(make(5), 3), _take(make(5), 3), _take(make(6), 3)
    assert all(_equal(x, y) for x, y in zip(a, b))
    assert not all(_equal(x, y) for x, y in zip(a, c))
    assert a[0]["image"].shape == (2, 16, 16, 3) and a[0]["label"].shape == (2, 16, 16)
    assert a[0]["image"].dtype == np.uint8 and a[0]["label"].dtype == np.uint8


@pytest.mark.parametrize("num_threads", [0, 2])
def test_restored_iterator_yields_the_same_next_batches(num_threads):
    make = lambda: training_batches(SCENES, batch_size=2, augment=CROP, seed=3,  # noqa: E731
                                    process_index=0, process_count=1, num_threads=num_threads)
    iterator = make()
    _take(iterator, 2)
    state = iterator.get_state()
    expected = _take(iterator, 3)
    resumed = make()
    resumed.set_state(state)
    assert all(_equal(x, y) for x, y in zip(expected, _take(resumed, 3)))


def test_each_epoch_visits_every_record_once_in_a_new_order():
    iterator = training_batches(_Numbered(12), batch_size=3, augment=IDENTITY, seed=0, num_epochs=2,
                                process_index=0, process_count=1)
    order = [i for batch in iterator for i in _ids(batch)]
    assert sorted(order[:12]) == list(range(12)) and sorted(order[12:]) == list(range(12))
    assert order[:12] != order[12:] and order[:12] != list(range(12))


def test_processes_take_disjoint_interleaved_batches_of_equal_count():
    def run(index, count):
        return [_ids(batch) for batch in training_batches(
            _Numbered(14), batch_size=2, augment=IDENTITY, seed=9, num_epochs=1,
            process_index=index, process_count=count)]

    single = run(0, 1)  # 7 global batches
    shards = [run(p, 3) for p in range(3)]
    assert [len(s) for s in shards] == [2, 2, 2]  # the 7th batch is dropped so no process waits
    for p, shard in enumerate(shards):
        assert shard == single[p:6:3]


def test_bad_arguments_raise_value_error():
    with pytest.raises(ValueError, match="batch_size"):
        training_batches(_Numbered(4), batch_size=0, augment=IDENTITY, process_index=0, process_count=1)
    with pytest.raises(ValueError, match="source"):
        training_batches(_Numbered(2), batch_size=3, augment=IDENTITY, process_index=0, process_count=1)
    with pytest.raises(ValueError, match="process_index"):
        training_batches(_Numbered(4), batch_size=2, augment=IDENTITY, process_index=2, process_count=2)


def test_process_defaults_come_from_jax():
    batch = next(training_batches(_Numbered(4), batch_size=2, augment=IDENTITY, seed=1))
    assert batch["label"].shape == (2, 4, 4)


def test_evaluation_batches_stack_frames_in_order_and_shard_by_process():
    source = SyntheticScenes("anomaly", 5, seed=2, height=16, width=24)
    batches = list(evaluation_batches(source, batch_size=2, process_index=0, process_count=1))
    assert [len(b["name"]) for b in batches] == [2, 2, 1]
    for i in range(5):
        batch, row = batches[i // 2], i % 2
        for key in ("image", "label", "depth"):
            np.testing.assert_array_equal(batch[key][row], source[i][key])
        assert batch["name"][row] == source[i]["name"]
    second = list(evaluation_batches(source, batch_size=2, process_index=1, process_count=2))
    assert len(second) == 1 and list(second[0]["name"]) == [source[2]["name"], source[3]["name"]]
