"""``predict_images`` with decode-ahead and write-behind threads writes the bytes one thread writes:
the same files after a corrupt frame, a map float16 cannot hold or the device out of memory, the
same exception, and no thread or temporary file left behind; one thread starts no thread."""
import threading

import cv2
import jax.numpy as jnp
import numpy as np
import pytest
from jax.errors import JaxRuntimeError

from jaxanom.app import predict as app_predict
from jaxanom.app.evaluate import predictor
from jaxanom.app.predict import DeviceOutOfMemory, PredictSettings, Scorer, predict_images, settings_record
from jaxanom.errors import InputError
from tiny_models import TinySegNet, numpy_variables

WORKING = (16, 24)
# native sizes, odd and of both aspects, so that every map is resized back (bilinear) before it is written
SHAPES = [(20, 30), (16, 24), (33, 17), (9, 40), (25, 25), (12, 31)]


@pytest.fixture(scope="module")
def network():
    model = TinySegNet(num_classes=6)
    return predictor(model, numpy_variables(model))


def write_frames(folder, corrupt=()):
    """PNG frames f0, f1, ... of ``SHAPES``; those in ``corrupt`` hold bytes no decoder reads."""
    folder.mkdir()
    rng = np.random.default_rng(0)
    paths = []
    for index, shape in enumerate(SHAPES):
        paths.append(folder / f"f{index}.png")
        if index in corrupt:
            paths[-1].write_bytes(b"not an image")
        else:
            cv2.imwrite(str(paths[-1]), rng.integers(0, 256, (*shape, 3), dtype=np.uint8))
    return paths


def contents(out):
    """Every file under ``out``: relative path -> bytes (temporaries included: there must be none)."""
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def run(paths, out, scorer):
    """``predict_images``' summary or exception, the files it left, and that no thread of it runs on."""
    try:
        result = predict_images(paths, out, scorer, progress=False)
    except Exception as error:  # noqa: BLE001  compared between thread counts
        result = (type(error), str(error))
    assert not [t.name for t in threading.enumerate() if t.name.startswith("predict-")]
    return result, contents(out)


@pytest.mark.parametrize("threads,batch_size", [(3, 1), (2, 2), (4, 3)])
def test_threads_write_the_bytes_of_one_thread_up_to_a_corrupt_frame(network, tmp_path, threads, batch_size):
    paths = write_frames(tmp_path / "images", corrupt={3})
    formats = ("npy", "png", "smiyc") if threads == 3 else ("npy",)  # the slow PNG panels once

    def scorer(threads, batch_size):
        settings = PredictSettings(("msp", "energy"), formats, size=WORKING, batch_size=batch_size,
                                   dataset="ObstacleTrack-all", threads=threads)
        return Scorer(network, settings)

    serial = run(paths, tmp_path / "serial", scorer(1, 1))
    threaded = run(paths, tmp_path / "threaded", scorer(threads, batch_size))
    assert issubclass(serial[0][0], ValueError) and "f3.png" in serial[0][1]
    assert threaded[0] == serial[0]
    names = {name.rsplit("/", 1)[-1] for name in serial[1]}
    assert names == {f"f{k}.{fmt}" for k in range(3) for fmt in ("npy", "png", "hdf5")[:len(formats)]}
    assert threaded[1] == serial[1]
    assert run(paths[:3], tmp_path / "whole", scorer(threads, batch_size))[0]["written"] == 3


class MapScorer:
    """A scorer without network: each frame's maps are its input's mean over the channels, times 1e5
    for ``energy`` of the frames named in ``huge`` (beyond float16); ``failing`` frames' dispatch
    raises ``error``."""

    def __init__(self, threads, batch_size, huge=(), failing=(), error=None):
        self.settings = PredictSettings(("msp", "energy"), size=WORKING, batch_size=batch_size, threads=threads)
        self.huge, self.failing, self.error = huge, failing, error

    def __call__(self, batch):
        if any(frame["name"] in self.failing for frame in batch):
            raise self.error
        maps = []
        for frame in batch:
            value = jnp.asarray(frame["input"], jnp.float32).mean(-1)[None]
            maps.append({"msp": value, "energy": value * (1e5 if frame["name"] in self.huge else 1.0)})
        return maps


@pytest.mark.parametrize("threads,batch_size", [(3, 1), (2, 2)])
def test_a_map_float16_cannot_hold_stops_at_its_frame_with_any_threads(tmp_path, threads, batch_size):
    paths = write_frames(tmp_path / "images")
    serial = run(paths, tmp_path / "serial", MapScorer(1, 1, huge={"f2"}))
    threaded = run(paths, tmp_path / "threaded", MapScorer(threads, batch_size, huge={"f2"}))
    assert serial[0][0] is InputError and "method 'energy': scores of f2 are not finite in float16" in serial[0][1]
    assert threaded[0] == serial[0]
    # the frames before, and f2's map of the method before the one that failed; nothing after
    assert sorted(serial[1]) == ["npy/energy/f0.npy", "npy/energy/f1.npy", "npy/msp/f0.npy", "npy/msp/f1.npy",
                                 "npy/msp/f2.npy"]
    assert threaded[1] == serial[1]


@pytest.mark.parametrize("threads,batch_size", [(3, 1), (2, 2)])
def test_device_out_of_memory_counts_the_frames_written_with_any_threads(tmp_path, threads, batch_size):
    paths = write_frames(tmp_path / "images")
    error = JaxRuntimeError("RESOURCE_EXHAUSTED: out of memory while trying to allocate")
    serial = run(paths, tmp_path / "serial", MapScorer(1, batch_size, failing={"f4"}, error=error))
    threaded = run(paths, tmp_path / "threaded", MapScorer(threads, batch_size, failing={"f4"}, error=error))
    assert serial[0][0] is DeviceOutOfMemory and "; 4 frames written" in serial[0][1] and len(serial[1]) == 8
    assert threaded == serial


def test_an_unexpected_error_keeps_the_frames_one_thread_wrote(tmp_path):
    """A bug's exception (not caught by predict) leaves what one thread had written before it."""
    paths = write_frames(tmp_path / "images")
    serial = run(paths, tmp_path / "serial", MapScorer(1, 1, failing={"f5"}, error=RuntimeError("a bug")))
    threaded = run(paths, tmp_path / "threaded", MapScorer(4, 1, failing={"f5"}, error=RuntimeError("a bug")))
    assert serial[0] == (RuntimeError, "a bug") and len(serial[1]) == 8  # f0 .. f3: f4 was on the device
    assert threaded == serial


def test_one_thread_starts_no_thread_and_works_in_the_calling_thread(tmp_path, monkeypatch):
    paths = write_frames(tmp_path / "images")
    callers = set()
    decode, stage = app_predict._decode, app_predict.stage_frame

    def spy(function):
        def called(*args):
            callers.add(threading.current_thread())
            return function(*args)
        return called

    def no_pool(*args, **kwargs):
        raise AssertionError("one thread must start no pool")

    monkeypatch.setattr(app_predict, "_decode", spy(decode))
    monkeypatch.setattr(app_predict, "stage_frame", spy(stage))
    monkeypatch.setattr(app_predict, "ThreadPoolExecutor", no_pool)
    assert predict_images(paths, tmp_path / "out", MapScorer(1, 2), progress=False)["written"] == len(SHAPES)
    assert callers == {threading.current_thread()}
    monkeypatch.undo()
    monkeypatch.setattr(app_predict, "_decode", spy(decode))
    monkeypatch.setattr(app_predict, "stage_frame", spy(stage))
    predict_images(paths, tmp_path / "out2", MapScorer(2, 2), progress=False)
    assert len(callers) > 1  # the spies see the pools' threads


def test_threads_are_checked_set_by_name_and_not_part_of_the_record(monkeypatch):
    from jaxanom.app.commands.inputs import with_overrides

    with pytest.raises(InputError, match=r"threads: expected >= 1 .*got 0"):
        PredictSettings(("msp",), threads=0)
    assert with_overrides(PredictSettings(("msp",)), ["threads=2"]).threads == 2
    records = [settings_record(PredictSettings(("msp",), threads=t), network="n", statistics=None, read_from={})
               for t in (None, 1, 7)]
    assert records[0] == records[1] == records[2] and "threads" not in records[0]
    for cpus, threads in [(1, 1), (2, 1), (3, 1), (16, 8), (64, 8)]:
        monkeypatch.setattr(app_predict.os, "sched_getaffinity", lambda _, n=cpus: set(range(n)), raising=False)
        assert app_predict.default_threads() == threads
