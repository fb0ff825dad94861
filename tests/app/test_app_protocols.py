"""Evaluation protocols (``jaxanom.protocols``): which frames count, at which size."""
import numpy as np
import pytest
from PIL import Image

from jaxanom.errors import InputError
from jaxanom.protocols import Protocol, get_protocol, resize_frame


def frame(label_values, shape=(36, 64), name="f"):
    rng = np.random.default_rng(len(label_values))
    label = rng.choice(np.array(label_values, np.uint8), size=shape)
    return {"image": rng.integers(0, 256, (*shape, 3), dtype=np.uint8), "label": label, "name": name}


def test_community_protocol_resizes_as_pil_and_skips_frames_without_anomaly():
    protocol = get_protocol("erfnet-community")
    frames = [frame([0, 1, 255], name="a"), frame([0, 255], name="b"), frame([0, 1], shape=(1080 // 30, 1920 // 30),
                                                                          name="c")]
    kept = list(protocol.frames(frames))
    assert [f["name"] for f in kept] == ["a", "c"]
    for got, source in zip(kept, (frames[0], frames[2])):
        assert got["image"].shape == (512, 1024, 3) and got["label"].shape == (512, 1024)
        expected = np.asarray(Image.fromarray(source["label"]).resize((1024, 512), Image.NEAREST))
        np.testing.assert_array_equal(got["label"], expected)
        pil = np.asarray(Image.fromarray(source["image"]).resize((1024, 512), Image.BILINEAR))
        np.testing.assert_array_equal(got["image"], pil)


def test_anomaly_lost_by_the_label_resize_skips_the_frame():
    """The community checks for an anomaly pixel after resizing the label (their loop's order)."""
    record = frame([0])
    record["label"][5, 5] = 1  # one pixel that nearest-neighbour shrinking to 4x4 does not sample
    protocol = Protocol("t", "test", size=(4, 4), skip_frames_without_anomaly=True)
    assert list(protocol.frames([record])) == []


def test_native_protocol_passes_frames_unchanged():
    frames = [frame([0, 255]), frame([0, 1])]
    kept = list(get_protocol("native").frames(frames))
    assert len(kept) == 2 and all(np.array_equal(a["image"], b["image"]) for a, b in zip(kept, frames))


def test_unknown_protocol_is_refused():
    with pytest.raises(InputError, match="^protocol: expected one of native, erfnet-community, got 'erfnet'"):
        get_protocol("erfnet")


def test_resizing_leaves_depth_out_and_resizes_the_road_region_as_the_labels():
    """A synthetic or Lost and Found frame: its depth is no input of the protocols' networks; its
    road region is a mask, resized by PIL's nearest as the labels are."""
    record = frame([0, 1])
    rng = np.random.default_rng(7)
    record.update(depth=np.ones((36, 64), np.float32), disparity=np.ones((36, 64), np.float32),
                  roi=rng.random((36, 64)) < 0.5)
    resized = resize_frame(record, (16, 24))
    assert sorted(resized) == ["image", "label", "name", "roi"]
    expected = np.asarray(Image.fromarray(record["roi"].astype(np.uint8)).resize((24, 16), Image.NEAREST)) == 1
    np.testing.assert_array_equal(resized["roi"], expected)
    assert resized["roi"].dtype == bool


def test_dropping_void_changes_every_method_but_void():
    """``drop_void``: MSP over the 19 trainIds (the community's ERFNet scores); the void method still
    reads the softmax of all 20 outputs."""
    from jaxanom.app.scoring import inputs_of, score_all

    logits = np.random.default_rng(3).normal(size=(1, 5, 6, 20)).astype(np.float32) * 4
    logits[0, 0, 0, 19] = 40.0  # a pixel the void channel wins: its MSP differs with and without it
    scores, _ = score_all(["msp", "void"], inputs_of({"logits": logits}), drop_void=True)
    kept = np.exp(logits[..., :19] - logits[..., :19].max(-1, keepdims=True))
    np.testing.assert_allclose(np.asarray(scores["msp"]), 1 - (kept / kept.sum(-1, keepdims=True)).max(-1), atol=1e-6)
    every = np.exp(logits - logits.max(-1, keepdims=True))
    np.testing.assert_allclose(np.asarray(scores["void"]), (every / every.sum(-1, keepdims=True))[..., 19], atol=1e-6)
    kept_all, _ = score_all(["msp"], inputs_of({"logits": logits}))
    assert not np.allclose(np.asarray(kept_all["msp"]), np.asarray(scores["msp"]))


def test_protocol_predictions_skip_frames_before_the_network_runs():
    from jaxanom.app.evaluate import protocol_predictions

    class Frames:
        def __init__(self, records):
            self.records = records

        def __len__(self):
            return len(self.records)

        def __getitem__(self, index):
            return self.records[index]

    seen = []

    def predict(images):
        seen.append(images.shape)
        return {"logits": np.zeros((*images.shape[:3], 20), np.float32)}

    protocol = Protocol("t", "test", size=(8, 16), skip_frames_without_anomaly=True)
    skipped = []
    batches = list(protocol_predictions(predict, Frames([frame([0, 1], name="a"), frame([0, 255], name="b")]),
                                        protocol, skipped))
    assert [str(b["name"][0]) for b in batches] == ["a"] and skipped == ["b"]
    assert seen == [(1, 8, 16, 3)] and batches[0]["label"].shape == (1, 8, 16)


def test_evaluate_refuses_a_resizing_protocol_without_a_run(tmp_path, capsys):
    from jaxanom.cli import main

    (tmp_path / "maps").mkdir()
    code = main(["evaluate", "--maps", str(tmp_path / "maps"), "--protocol", "erfnet-community", "--dataset",
                 "road-anomaly", "--path", str(tmp_path), "--out", str(tmp_path / "out")])
    assert code == 2 and "--protocol erfnet-community: resizes the frames the network sees, so it needs --run" \
        in capsys.readouterr().err
