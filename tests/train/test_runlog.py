"""A run's log after a kill: the lines past the resumed step go, those before stay, TensorBoard is told."""
import json
import struct

from tensorboardX.proto import event_pb2

from jaxanom.train.runlog import RunLog


def _starts(path):
    """The steps of the session starts (purges) in the TFRecord event file ``path`` (length, crc, data, crc)."""
    data, steps = path.read_bytes(), []
    while data:
        (length,) = struct.unpack("<Q", data[:8])
        event = event_pb2.Event.FromString(data[12:12 + length])
        steps += [event.step] if event.session_log.status == event_pb2.SessionLog.START else []
        data = data[16 + length:]
    return steps


def test_a_resumed_log_drops_the_steps_it_repeats_and_keeps_the_earlier_ones(tmp_path):
    log = RunLog(tmp_path)
    for step in range(1, 6):
        log.scalars(step, {"loss": float(step)})
    log.close()
    with open(tmp_path / "log.jsonl", "a") as f:
        f.write('{"step": 6, "ti')  # a line a kill cut short
    resumed = RunLog(tmp_path)  # resumed from the checkpoint of step 3
    resumed.scalars(4, {"loss": 40.0})
    resumed.close()
    lines = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert [(line["step"], line["loss"]) for line in lines] == [(1, 1.0), (2, 2.0), (3, 3.0), (4, 40.0)]
    # TensorBoard: the resumed writer's file starts with a purge at step 4 (a reader hides older events from it on)
    assert sorted(step for path in (tmp_path / "tensorboard").iterdir() for step in _starts(path)) == [4]


def test_a_fresh_log_starts_empty_and_purges_nothing(tmp_path):
    log = RunLog(tmp_path)
    log.scalars(1, {"loss": 1.0})
    log.close()
    assert [json.loads(line)["step"] for line in (tmp_path / "log.jsonl").read_text().splitlines()] == [1]
    (events,) = (tmp_path / "tensorboard").iterdir()
    assert _starts(events) == []
