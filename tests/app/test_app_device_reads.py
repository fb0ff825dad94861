"""The batch loops of ``predict`` and ``evaluate`` read nothing back from the device but what they
write and check: no read waits for a batch's computation before the next batch is dispatched, so
on an accelerator the next batch is decoded and dispatched while the device works. Reads are counted with ``host_reads`` (the CPU
backend does not enforce ``jax.transfer_guard`` for them)."""
from collections import Counter

import cv2
import numpy as np
import pytest

from host_reads import count_host_reads
from jaxanom.app.evaluate import anomaly_results, predictions, predictor
from jaxanom.app.predict import PredictSettings, Scorer, predict_images
from jaxanom.metrics import AnomalyMetricAccumulator
from tiny_models import TinySegNet, numpy_variables

SIZE, FRAMES, CLASSES = (16, 24), 3, 20  # 20 outputs: a void channel, for the void method
# a method of each paper module a run without MMF pipeline can score with; not the *_superpixel rows,
# whose SLIC takes seconds to compile (their batched functions check through the same _validate)
METHODS = ("msp", "sml_post", "cudam", "void")


@pytest.fixture(scope="module")
def network():
    """The jitted predictor of a tiny CuDAM network and SML statistics (NumPy, as read from a file)."""
    model = TinySegNet(num_classes=CLASSES, head="cudam")
    rng = np.random.default_rng(0)
    stats = (rng.normal(size=CLASSES).astype(np.float32), rng.uniform(0.5, 2, CLASSES).astype(np.float32))
    return predictor(model, numpy_variables(model)), stats


def frames(seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (*SIZE, 3), dtype=np.uint8) for _ in range(FRAMES)]


class CountingScorer:
    """A ``Scorer`` that counts the batches dispatched to it."""

    def __init__(self, scorer: Scorer):
        self.scorer, self.settings, self.dispatched = scorer, scorer.settings, 0

    def __call__(self, batch):
        self.dispatched += 1
        return self.scorer(batch)


def test_predict_reads_each_map_once_after_the_next_frame_is_dispatched(network, tmp_path, monkeypatch):
    predict, stats = network
    paths = []
    for index, image in enumerate(frames()):
        paths.append(tmp_path / f"frame{index}.png")
        cv2.imwrite(str(paths[-1]), image)
    scorer = CountingScorer(Scorer(predict, PredictSettings(METHODS), stats))
    reads = count_host_reads(monkeypatch, lambda: scorer.dispatched)
    assert predict_images(paths, tmp_path / "out", scorer, progress=False)["written"] == FRAMES
    # frame k's maps are read once each, when frame k + 1 is on the device (the last frame's after it)
    expected = Counter({k + 1: len(METHODS) for k in range(1, FRAMES)})
    expected[FRAMES] += len(METHODS)
    assert Counter(reads) == expected, f"{len(METHODS)} methods: {sorted(Counter(reads).items())}"


def test_evaluate_reads_the_device_only_to_accumulate_metrics_after_the_next_batch_is_dispatched(network, monkeypatch):
    predict, stats = network
    rng = np.random.default_rng(1)
    batches = [{"image": image[None], "label": rng.choice(np.array([0, 1, 255], np.uint8), (1, *SIZE))}
               for image in frames(1)]
    phase = ["loop"]  # where a read happens: the batch loop, or a metric accumulator's update / compute
    for name in ("update", "compute"):
        method = getattr(AnomalyMetricAccumulator, name)

        def counted(self, *args, _name=name, _method=method, **kwargs):
            phase[0] = _name
            try:
                return _method(self, *args, **kwargs)
            finally:
                phase[0] = "loop"

        monkeypatch.setattr(AnomalyMetricAccumulator, name, counted)
    dispatched = [0]

    def counted_predict(images):
        dispatched[0] += 1
        return predict(images)

    reads = count_host_reads(monkeypatch, lambda: (phase[0], dispatched[0]))
    anomaly_results(predictions(counted_predict, batches), METHODS, stats=stats)
    assert {where for where, _ in reads} == {"loop", "update", "compute"}, Counter(reads)
    # batch k's scores are read once batch k + 1 is on the device (the last batch's after it): in the loop,
    # one count of non-finite scores per map (method_registry.check_finite), then by the accumulators
    assert {at for where, at in reads if where != "compute"} == set(range(2, FRAMES + 1)), Counter(reads)
    assert Counter(where for where, _ in reads)["loop"] == FRAMES * len(METHODS), Counter(reads)


def test_predictions_keep_the_order_and_run_one_batch_ahead():
    calls = []

    def predict(images):
        calls.append(int(images[0]))
        return {"logits": images * 10}

    seen = [(int(out["logits"][0]), out["name"], len(calls))
            for out in predictions(predict, ({"image": np.array([k]), "name": f"f{k}"} for k in range(4)))]
    assert seen == [(0, "f0", 2), (10, "f1", 3), (20, "f2", 4), (30, "f3", 4)]
