"""``evaluate`` with SegmentMeIfYouCan's component metrics (pooled and per frame), every AP / FPR
convention, and real RoadObstacle21 / RoadAnomaly21 frames through the command."""
import json

import numpy as np
import pytest
from sklearn.metrics import average_precision_score, roc_auc_score

from conftest import REALDATA
from jaxanom.app.evaluate import anomaly_results
from component_scenes import one_predicted_component_over_two_objects, small_object_under_a_prediction
from converted_run import tiny_run  # noqa: F401  (the fixture)


def logits_for(mask: np.ndarray) -> np.ndarray:
    """Two-class logits whose MSP (1 - max softmax) is 0.5 on ``mask`` and ~4.5e-5 elsewhere."""
    logits = np.zeros((*mask.shape, 2), np.float32)
    logits[..., 0] = np.where(mask, 0.0, 10.0)
    return logits


def test_components_pooled_and_per_frame_by_hand():
    frames = [one_predicted_component_over_two_objects(), small_object_under_a_prediction()]
    batches = [{"logits": logits_for(s > 0)[None], "label": l[None], "name": np.array([f"f{i}"])}
               for i, (s, l) in enumerate(frames)]
    metrics, _ = anomaly_results(iter(batches), ["msp"], track="obstacle")
    m = metrics["msp"]
    assert m["components"]["threshold"] == pytest.approx(0.5)  # the pooled best-F1 pixel threshold
    assert m["components"]["f1"][0] == pytest.approx(6 / 8)  # hand-worked in test_metrics_components
    assert [f["name"] for f in m["frames"]] == ["f0", "f1"]
    first, second = (f["components"] for f in m["frames"])
    assert first["f1_mean"] == pytest.approx((4 * 0.8 + 3 * 0.5) / 11)
    assert second["f1_mean"] == pytest.approx(8 / 33)
    assert first["tp"] == [2] * 4 + [1] * 3 + [0] * 4 and second["fp"] == [1] * 4 + [2] * 7
    assert m["components"]["num_truth"] == 3 and m["components"]["num_predicted"] == 4
    for frame, (scores, labels) in zip(m["frames"], frames):  # per-frame pixel metrics: scikit-learn
        score = 1 - 1 / (1 + np.exp(-np.where(scores > 0, 0.0, 10.0)))
        keep = labels != 255
        assert frame["ap"] == pytest.approx(average_precision_score(labels[keep], score[keep]), rel=1e-6)
        assert frame["auroc"] == pytest.approx(roc_auc_score(labels[keep], score[keep]), rel=1e-6)


def test_every_convention_from_one_computation():
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(2, 12, 14, 3)).astype(np.float32)
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(2, 12, 14), p=[0.6, 0.3, 0.1])
    metrics, _ = anomaly_results(iter([{"logits": logits, "label": labels}]), ["max_logit"])
    m = metrics["max_logit"]
    keep = labels != 255
    assert m["ap_conventions"]["step"] == pytest.approx(average_precision_score(labels[keep], -logits.max(-1)[keep]))
    assert set(m["ap_conventions"]) == {"step", "trapz", "envelope"}
    assert set(m["fpr_conventions"]) == {"first", "interp", "nearest", "strict"}
    assert m["fpr_conventions"]["first"] == m["fpr_at_tpr"] and "frames" not in m


@pytest.fixture(scope="module")
def obstacle_subset(tmp_path_factory):
    """Two RoadObstacle21 frames in the track's layout (symbolic links to the shared files)."""
    source = REALDATA / "RoadObstacle21"
    if not source.is_dir():
        pytest.skip(f"RoadObstacle21 not found at {source} (set JAXANOM_REALDATA)")
    root = tmp_path_factory.mktemp("ro21")
    for folder in ("images", "labels_masks"):
        (root / folder).mkdir()
    for frame in ("1", "2"):
        (root / "images" / f"{frame}.webp").symlink_to(source / "images" / f"{frame}.webp")
        name = f"{frame}_labels_semantic.png"
        (root / "labels_masks" / name).symlink_to(source / "labels_masks" / name)
    return root


def test_evaluate_real_obstacle_frames_in_the_road_region(tiny_run, obstacle_subset, tmp_path, capsys):  # noqa: F811
    import cv2

    from jaxanom.cli import main

    out = tmp_path / "eval"
    assert main(["evaluate", "--run", str(tiny_run), "--dataset", "smiyc", "--track", "obstacle", "--path",
                 str(obstacle_subset), "--methods", "msp,entropy", "--out", str(out), "--all-conventions"]) == 0
    printed = capsys.readouterr().out
    assert "| mean F1 |" in printed and "AP envelope" in printed and "FPR@95 strict" in printed
    record = json.loads((out / "metrics.json").read_text())
    labels = [cv2.imread(str(obstacle_subset / "labels_masks" / f"{f}_labels_semantic.png"), cv2.IMREAD_UNCHANGED)
              for f in ("1", "2")]
    for m in record["metrics"].values():
        # scored in the road region only: everything off the road is void in the track's labels
        assert m["num_void"] == sum(int((l == 255).sum()) for l in labels)
        assert m["num_positives"] == sum(int((l == 1).sum()) for l in labels)
        assert m["components"]["track"] == "obstacle" and len(m["components"]["f1"]) == 11
        assert [f["name"] for f in m["frames"]] == ["1", "2"]
        assert all(0 <= f["ap"] <= 1 and "f1_mean" in f["components"] for f in m["frames"])


def test_evaluate_smiyc_needs_its_track(tiny_run, obstacle_subset, tmp_path, capsys):  # noqa: F811
    from jaxanom.cli import main

    code = main(["evaluate", "--run", str(tiny_run), "--dataset", "smiyc", "--path", str(obstacle_subset),
                 "--methods", "msp", "--out", str(tmp_path / "o")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "--track" in error and len(error.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_the_evaluators_of_anomaly_results_merge_parts_as_one_pass():
    from jaxanom.app.evaluate import _Curves, _FramePixels, _Frames, _OptionsUsed

    rng = np.random.default_rng(0)
    options = [{"s": {"k": 1}}, {"s": {"k": 2}, "t": {"j": 1}}, {"s": {"k": 1}, "t": {"j": 3}}]
    batches = [{"scores": {"s": rng.random((2, 5, 6))}, "label": (rng.random((2, 5, 6)) < 0.3).astype(np.uint8),
                "name": [f"a{b}", None], "options": used} for b, used in enumerate(options)]

    def fold(evaluator, part):
        state = evaluator.init()
        for batch in part:
            state = evaluator.update(state, batch)
        return state

    for evaluator in (_Frames(), _OptionsUsed(), _Curves("s"), _FramePixels("s", "first", "step")):
        one_pass = evaluator.finalize(fold(evaluator, batches))
        first, second = fold(evaluator, batches[:1]), fold(evaluator, batches[1:])
        np.testing.assert_equal(evaluator.finalize(evaluator.merge(first, second)), one_pass)
        np.testing.assert_equal(evaluator.finalize(first), evaluator.finalize(fold(evaluator, batches[:1])))
    assert _OptionsUsed().finalize(fold(_OptionsUsed(), batches)) == {"s": {"k": [1, 2]}, "t": {"j": [1, 3]}}
    assert _Frames().finalize(fold(_Frames(), batches))["names"] == ["a0", "1", "a1", "3", "a2", "5"]
