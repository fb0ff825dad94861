"""The official SegmentMeIfYouCan kit's convention (``jaxanom.metrics.smiyc``, ``evaluate
--convention smiyc``) against the kit's own numbers.

Expected numbers come from running the kit's code, never this project's: github
SegmentMeIfYouCan/road-anomaly-benchmark at commit 1c7804e0749686452eb02bbcfb81234e38795f8a, in a
separate Python 3.11 environment with its pinned NumPy 1.23.3 (scipy 1.9.3, h5py 3.8.0,
easydict 1.10). A driver called, per frame, ``MetricRegistry.get("PixBinaryClass").process_frame(
label_pixel_gt=labels, anomaly_p=float16 scores)``, then its ``aggregate`` (AP = ``area_PRC``,
AUROC = ``area_ROC``, FPR95 = ``tpr95_fpr``, ``best_f1_threshold``), then
``MetricRegistry.get("SegEval-AnomalyTrack" | "SegEval-ObstacleTrack")`` with ``cfg.thresh_p =
np.float64(best_f1_threshold)`` (what h5py reads back from the kit's saved curve) through its
``process_frame`` / ``aggregate`` (sIoU = ``sIoU_gt``, PPV = ``prec_pred``, mean F1 = ``f1_mean``).
Its inputs were the frames these tests build (``synthetic_frames``, ``real_frames``); the kit
cannot take the all-void frame (``np.min`` of nothing), so its numbers are of the others.
"""
import json

import numpy as np
import pytest

from conftest import REALDATA
from jaxanom.metrics import smiyc_component_metrics, smiyc_pixel_metrics
from jaxanom.metrics.smiyc import _numpy_quantiles, above_threshold, binned_metrics, frame_bins, to_unit_interval


def synthetic_frames():
    """Seven (scores float32, labels uint8) frames with the awkward cases: coarse scores (many
    ties within and across frames), a frame without anomaly, an all-void frame, scores up to
    +-6e4 (their range overflows float16: the kit's outer edges become +-inf), values in [0, 1],
    and more than 384 pixels of a class (quantiles that do bin)."""
    rng = np.random.default_rng(20231)
    frames = []
    h, w = 46, 62  # one size: evaluate compiles its exact per-frame metrics once
    for index in range(7):
        labels = np.zeros((h, w), np.uint8)
        labels[: h // 6] = 255  # void band (sky)
        if index != 1:  # frame 1: no anomaly
            for _ in range(rng.integers(1, 4)):
                y, x = rng.integers(h // 6, h - 8), rng.integers(0, w - 8)
                labels[y:y + rng.integers(4, 12), x:x + rng.integers(4, 14)] = 1
        if index == 2:
            labels[:] = 255  # all void
        if index == 5:
            labels[8:28, 4:30] = 1  # 520 anomaly pixels: their quantiles bin too
        scores = rng.normal(size=(h, w)) + 1.6 * (labels == 1) + 0.3 * rng.normal()
        if index == 0:
            scores = np.round(scores * 4) / 4  # ties
        elif index == 3:
            scores = np.clip(scores * 2e4, -6e4, 6e4)  # huge
        elif index == 4:
            scores = 1 / (1 + np.exp(-scores))  # in [0, 1]
        elif index == 6:
            scores = np.round(scores, 1)  # ties shared with frame 0's values
        frames.append((scores.astype(np.float32), labels))
    return frames


def real_frames(track: str):
    """Two real frames of a track (labels read as the kit reads them: 0, 1, else 255) with two
    score maps computed by NumPy alone (no network: cheap and exactly reproducible): ``redness``
    = (R - G) / 255 of the image (256 levels: ties everywhere) and ``blurred_truth``, the anomaly
    mask averaged over 9 shifts of up to 12 pixels plus 0.3 |gray - gray 7 columns left| / 255
    (components of real shapes that partly overlap the truth). None when the files are absent."""
    from jaxanom.data.image_io import read_label, read_rgb

    folder = REALDATA / ("RoadAnomaly21" if track == "anomaly" else "RoadObstacle21")
    names = ("0", "8") if track == "anomaly" else ("12", "27")
    if not folder.is_dir():
        return None
    maps = {"redness": [], "blurred_truth": []}
    labels = []
    for name in names:
        image = read_rgb(next((folder / "images").glob(f"{name}.*"))).astype(np.float32)
        raw = read_label(folder / "labels_masks" / f"{name}_labels_semantic.png")
        labels.append(np.where(raw <= 1, raw, 255).astype(np.uint8))
        maps["redness"].append((image[..., 0] - image[..., 1]) / 255)
        truth = (raw == 1).astype(np.float32)
        blurred = sum(np.roll(truth, (dy, dx), axis=(0, 1)) for dy in (-12, 0, 12) for dx in (-12, 0, 12)) / 9
        gray = image.mean(axis=-1)
        maps["blurred_truth"].append(blurred + 0.3 * np.abs(gray - np.roll(gray, 7, axis=1)) / 255)
    return maps, labels


# The kit's numbers (driver in the module docstring). Pixel numbers: ap, auroc, fpr95,
# tpr95_threshold, best_f1, best_f1_threshold; components per track: sIoU, PPV, mean F1.
KIT_SYNTHETIC = {  # synthetic_frames() without the all-void frame 2
    "pixels": (0.15932919917350818, 0.8121850499681716, 0.5515062454077884, -0.16974370971360966,
               0.31169608136404425, 1.000808277578329),  # an interpolated edge: the mask is score > 1.0009766
    "anomaly": (0.0, float("nan"), 0.0),  # no predicted component of 500 pixels: the mean PPV is 0 / 0
    "obstacle": (0.24401898066454597, 0.4761119695849214, 0.33100233100233095),
}
KIT_REAL = {  # real_frames(track)
    ("anomaly", "redness"): ((0.09479000659691039, 0.3957448262522271, 0.8400885279192962, -0.035308837890625,
                              0.2337506597601718, -0.035308837890625),
                             (0.030899212032680402, 0.02089064864535285, 0.0)),
    ("anomaly", "blurred_truth"): ((0.9975753847955572, 0.9996547409920423, 0.0009514090926078301, 0.572265625,
                                    0.9787652211066011, 0.46923828125),
                                   (0.6702251493316614, 0.8854859626009927, 0.8143775416502689)),
    ("obstacle", "redness"): ((0.021098761592672977, 0.46645046590275396, 0.998769503058766, -0.04705810546875,
                               0.02975724353954581, 0.07452392578125),
                              (0.17486338797814208, 0.9142857142857143, 0.3272727272727272)),
    # its best-F1 edge is interpolated (not a float16 value): the kit's mask is score > 0.497314453125
    ("obstacle", "blurred_truth"): ((0.9623123079668267, 0.9995739599626429, 0.0031306574857348944, 0.262939453125,
                                     0.9205803968018952, 0.4972691946801567),
                                    (0.22611966410076978, 0.956698741672835, 0.39999999999999997)),
}


def pixel_numbers(m: dict) -> tuple:
    return (m["ap"], m["auroc"], m["fpr_at_tpr"], m["threshold_at_tpr"], m["best_f1"], m["best_f1_threshold"])


def component_numbers(c: dict) -> tuple:
    return (c["mean_siou"], c["mean_ppv"], c["f1_mean"])


def test_synthetic_frames_equal_the_kit():
    scores, labels = zip(*synthetic_frames())
    # rel 1e-12: sums in another order than NumPy 1.23's differ in the last bits (seen: AUROC, 1 ulp)
    assert pixel_numbers(smiyc_pixel_metrics(scores, labels)) == pytest.approx(KIT_SYNTHETIC["pixels"], rel=1e-12)
    for track in ("anomaly", "obstacle"):
        result = smiyc_component_metrics(scores, labels, track=track)
        assert result["threshold"] == KIT_SYNTHETIC["pixels"][5]
        assert component_numbers(result) == pytest.approx(KIT_SYNTHETIC[track], rel=1e-12, nan_ok=True)


@pytest.mark.parametrize("track", ["anomaly", "obstacle"])
def test_real_frames_equal_the_kit(track):
    frames = real_frames(track)
    if frames is None:
        pytest.skip("shared real data absent")
    maps, labels = frames
    for name, scores in maps.items():
        pixels, components = KIT_REAL[(track, name)]
        assert pixel_numbers(smiyc_pixel_metrics(scores, labels)) == pytest.approx(pixels, rel=1e-12), name
        got = smiyc_component_metrics(scores, labels, track=track, threshold=pixels[5])
        assert component_numbers(got) == pytest.approx(components, rel=1e-12), name


def test_all_void_frame_adds_nothing():
    frames = synthetic_frames()
    assert np.all(frames[2][1] == 255)
    scores, labels = zip(*frames)
    without = [i for i in range(len(frames)) if i != 2]
    assert smiyc_pixel_metrics(scores, labels) == smiyc_pixel_metrics([scores[i] for i in without],
                                                                      [labels[i] for i in without])
    bins = frame_bins(*frames[2])
    assert bins.lower_edges.size == bins.positives.size == bins.negatives.size == 0


def test_frame_bins_by_hand():
    """Normal scores 1, 2 and anomaly scores 2, 4 (under 384 per class: every value is an edge):
    eps = max(0.01 * 3, 0.01) = 0.03, edges 0.97, 1, 2, 4, 4.03. The kit on this frame:
    AP 0.8333333333333333, AUROC 0.875, FPR95 0.5 at 2, best F1 0.8 at 2."""
    bins = frame_bins(np.array([[1.0, 2.0, 2.0, 4.0, 9.0]], np.float32), np.array([[0, 0, 1, 1, 255]], np.uint8))
    assert bins.lower_edges.tolist() == [1 - 3 * 0.01, 1.0, 2.0, 4.0]
    assert bins.positives.tolist() == [0, 0, 1, 1] and bins.negatives.tolist() == [0, 1, 1, 0]
    # points at 4, 2, 1, 0.97 after the origin: R = 1/2, 1, 1, 1; Prec = 1, 2/3, 1/2, 1/2; FPR = 0, 1/2, 1, 1
    result = binned_metrics([bins])
    assert result["ap"] == pytest.approx(0.5 + 1 / 3, rel=1e-15)
    assert result["auroc"] == pytest.approx(0.875, rel=1e-15)
    assert result["fpr_at_tpr"] == 0.5 and result["threshold_at_tpr"] == 2.0
    assert result["best_f1"] == pytest.approx(0.8) and result["best_f1_threshold"] == 2.0  # F1 2/3, 4/5, 2/3, 2/3


def test_a_shared_top_edge_keeps_the_first_entry():
    """Frame A: normal 3, anomaly 1; frame B: anomaly 3, normal 1. Both have the top edge 3; the
    later frame's pixels come first (B's anomaly alone: TP 1, FP 0), and the kit keeps that entry
    as a point before the edge's sum (TP 1, FP 1): AP = 1/2 + 1/2 * 1/2 = 0.75, AUROC 0.625, best
    F1 2/3 at 3. In the other frame order: AP 0.5, AUROC 0.375, best F1 2/3 at 1. The kit gives
    exactly these four numbers for both orders."""
    a = (np.array([[3.0, 1.0]], np.float32), np.array([[0, 1]], np.uint8))
    b = (np.array([[3.0, 1.0]], np.float32), np.array([[1, 0]], np.uint8))
    forward = smiyc_pixel_metrics(*zip(a, b))
    assert (forward["ap"], forward["auroc"], forward["best_f1_threshold"]) == (0.75, 0.625, 3.0)
    backward = smiyc_pixel_metrics(*zip(b, a))
    assert (backward["ap"], backward["auroc"], backward["best_f1_threshold"]) == (0.5, 0.375, 1.0)
    assert forward["fpr_at_tpr"] == backward["fpr_at_tpr"] == 1.0


def test_quantiles_subtract_neighbours_in_float16():
    """NumPy 1.23's ``np.quantile`` on float16: the median of 0.1 and 1000 is 1000 - (1000 - 0.1) / 2
    with 1000 - 0.0999755859375 rounded to float16 (1000): 500 exactly, not 500.04998779296875."""
    values = np.array([0.1, 1000], np.float16)
    assert _numpy_quantiles(values, 3).tolist() == [float(values[0]), 500.0, 1000.0]


def test_threshold_rounds_to_float16():
    """The kit compares float16 maps with a float16-rounded threshold: 0.9999 rounds to 1, so a
    score of 1 is not above it; 0.999 rounds to 0.99902, below 1."""
    scores = np.array([[1.0, 0.5]], np.float32)
    assert above_threshold(scores, 0.9999).tolist() == [[False, False]]
    assert above_threshold(scores, 0.999).tolist() == [[True, False]]


def test_bad_input_names_the_argument():
    labels = np.zeros((4, 5), np.uint8)
    labels[0, 0] = 1
    good = np.zeros((4, 5), np.float32)
    with pytest.raises(ValueError, match="labels: expected values in"):
        frame_bins(good, np.full((4, 5), 2, np.uint8))
    with pytest.raises(ValueError, match="float16's range"):
        frame_bins(np.full((4, 5), 7e4, np.float32), labels)
    with pytest.raises(ValueError, match="float16's range"):
        frame_bins(np.where(labels == 1, np.nan, 0).astype(np.float32), labels)
    with pytest.raises(ValueError, match="float16 can hold"):  # consecutive normal scores 1e5 apart: NaN edges
        frame_bins(np.where(np.arange(20).reshape(4, 5) % 2, 6e4, -6e4).astype(np.float32), labels)
    with pytest.raises(ValueError, match="no anomaly"):
        smiyc_pixel_metrics([good], [np.zeros((4, 5), np.uint8)])
    with pytest.raises(ValueError, match="labels_per_frame"):
        smiyc_pixel_metrics([good, good], [labels])
    with pytest.raises(ValueError, match="track"):
        smiyc_component_metrics([good], [labels], track="road")
    with pytest.raises(ValueError, match="labels: expected values in"):  # checked with a given threshold too
        smiyc_component_metrics([good], [np.full((4, 5), 7, np.uint8)], track="obstacle", threshold=0.5)


def test_evaluate_maps_from_predicts_tree_equal_the_kit(tmp_path, capsys):
    """``jaxanom evaluate --maps`` on the tree ``predict --format smiyc`` writes (float16 HDF5 maps)
    with ``--convention smiyc``: the kit's numbers, the exact ones kept beside them."""
    from jaxanom.cli import main

    root = _obstacle_track_and_maps(tmp_path)
    out = tmp_path / "eval"
    assert main(["evaluate", "--maps", str(tmp_path / "pred"), "--dataset", "smiyc", "--path", str(root),
                 "--track", "obstacle", "--convention", "smiyc", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| synthetic |" in printed and "SegmentMeIfYouCan kit's numbers" in printed
    record = json.loads((out / "metrics.json").read_text())
    assert record["convention"] == "smiyc" and record["maps"] == str(tmp_path / "pred")
    m = record["metrics"]["synthetic"]
    assert pixel_numbers(m) == pytest.approx(KIT_SYNTHETIC["pixels"], rel=1e-12)
    assert m["components"]["threshold"] == KIT_SYNTHETIC["pixels"][5]
    assert component_numbers(m["components"]) == pytest.approx(KIT_SYNTHETIC["obstacle"], rel=1e-12)
    assert set(m["exact"]) == {"ap", "auroc", "fpr_at_tpr", "best_f1", "best_f1_threshold", "ap_convention",
                               "fpr_convention", "ap_conventions", "fpr_conventions"}
    assert m["exact"]["ap"] != m["ap"] and m["exact"]["ap_conventions"]["step"] == m["exact"]["ap"]


def _obstacle_track_and_maps(tmp_path):
    """``synthetic_frames()`` as a RoadObstacle21 folder (returned) and its maps in ``tmp_path / "pred"``."""
    import cv2

    from jaxanom.app.predict import _write_hdf5, output_file

    root = tmp_path / "track"
    for folder in ("images", "labels_masks"):
        (root / folder).mkdir(parents=True)
    for index, (scores, labels) in enumerate(synthetic_frames()):
        cv2.imwrite(str(root / "images" / f"{index}.png"), np.zeros((*labels.shape, 3), np.uint8))
        cv2.imwrite(str(root / "labels_masks" / f"{index}_labels_semantic.png"), labels)
        path = output_file(tmp_path / "pred", str(index), "synthetic", "smiyc", "ObstacleTrack-all")
        path.parent.mkdir(parents=True, exist_ok=True)
        _write_hdf5(str(path), scores.astype(np.float16))
    return root


def test_every_number_of_metrics_json_carries_the_convention_that_made_it(tmp_path, capsys):
    """Every combination of --convention, --ap-convention and --fpr-convention: the top-level AP and
    FPR are the kit's under smiyc (labelled so, KIT_SYNTHETIC's) and the chosen exact conventions'
    otherwise; the exact numbers sit beside the labels of the conventions that made them."""
    from jaxanom.cli import main
    from jaxanom.metrics.anomaly import AP_CONVENTIONS, FPR_CONVENTIONS

    root = _obstacle_track_and_maps(tmp_path)
    for convention in ("exact", "smiyc"):
        for ap in AP_CONVENTIONS:
            for fpr in ("first", "interp"):
                out = tmp_path / f"{convention}_{ap}_{fpr}"
                assert main(["evaluate", "--maps", str(tmp_path / "pred"), "--dataset", "smiyc", "--path", str(root),
                             "--track", "none", "--convention", convention, "--ap-convention", ap,
                             "--fpr-convention", fpr, "--out", str(out)]) == 0
                m = json.loads((out / "metrics.json").read_text())["metrics"]["synthetic"]
                exact = m["exact"] if convention == "smiyc" else m
                assert (exact["ap_convention"], exact["fpr_convention"]) == (ap, fpr)
                assert set(exact["ap_conventions"]) == set(AP_CONVENTIONS)
                assert set(exact["fpr_conventions"]) == set(FPR_CONVENTIONS)
                assert exact["ap"] == exact["ap_conventions"][ap] and exact["fpr_at_tpr"] == exact["fpr_conventions"][fpr]
                if convention == "smiyc":  # the kit's numbers whatever the exact conventions, and no other label
                    assert m["convention"] == "smiyc"
                    assert pixel_numbers(m) == pytest.approx(KIT_SYNTHETIC["pixels"], rel=1e-12)
                    assert not {"ap_convention", "fpr_convention", "ap_conventions", "fpr_conventions"} & set(m)
    capsys.readouterr()


def test_evaluate_maps_names_what_is_missing(tmp_path, capsys):
    from jaxanom.cli import main

    root = tmp_path / "track"
    for folder in ("images", "labels_masks"):
        (root / folder).mkdir(parents=True)
    (root / "images" / "a.png").write_bytes(b"")  # never decoded: the maps are looked for first
    (root / "labels_masks" / "a_labels_semantic.png").write_bytes(b"")
    (tmp_path / "pred" / "anomaly_p" / "msp" / "ObstacleTrack-all").mkdir(parents=True)
    code = main(["evaluate", "--maps", str(tmp_path / "pred"), "--dataset", "smiyc", "--track", "obstacle",
                 "--path", str(root), "--out", str(tmp_path / "o")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "--maps: 1 of 1 frames have no map in" in error and "a.hdf5" in error
    assert len(error.splitlines()) == 1 and not (tmp_path / "o").exists()
    with pytest.raises(ValueError, match="convention: expected one of"):
        from jaxanom.app.evaluate import anomaly_results

        anomaly_results(iter([]), ["msp"], convention="kit")


def test_unit_interval_keeps_the_exact_metrics_not_the_kits():
    """The logistic map against its formula in float64; the exact metrics of the mapped synthetic
    scores equal the raw ones' (scikit-learn's AP and AUROC as the reference), the kit's change."""
    from sklearn.metrics import average_precision_score, roc_auc_score

    scores, labels = zip(*synthetic_frames())
    raw = [s for s in scores if np.abs(s).max() < 100]  # the huge frame saturates the map in float32
    kept = [l for s, l in zip(scores, labels) if np.abs(s).max() < 100]
    mapped = [np.asarray(to_unit_interval(s, 0.5, 2.0)) for s in raw]
    assert mapped[0].dtype == np.float32 and all(0 <= m.min() and m.max() <= 1 for m in mapped)
    np.testing.assert_allclose(mapped[0], 1 / (1 + np.exp(-(raw[0].astype(np.float64) - 0.5) / 2.0)), rtol=1e-6)
    keep = np.concatenate([l.ravel() for l in kept]) != 255
    truth = np.concatenate([l.ravel() for l in kept])[keep]
    for metric in (average_precision_score, roc_auc_score):
        before = metric(truth, np.concatenate([s.ravel() for s in raw])[keep])
        after = metric(truth, np.concatenate([m.ravel() for m in mapped])[keep])
        assert after == pytest.approx(before, rel=1e-12)
    assert smiyc_pixel_metrics(mapped, kept)["ap"] != smiyc_pixel_metrics(raw, kept)["ap"]


def test_predict_writes_the_unit_interval_map():
    """``PredictSettings.unit_interval`` (``predict --unit-interval``): the scorer's maps are the
    logistic of the method's scores; a bad pair is refused naming the setting."""
    from jaxanom.app.predict import PredictSettings, Scorer

    logits = np.random.default_rng(5).normal(size=(1, 6, 7, 4)).astype(np.float32) * 5
    network = lambda images: {"logits": logits}  # noqa: E731
    plain = Scorer(network, PredictSettings(methods=("max_logit",)))(
        [{"input": np.zeros((6, 7, 3), np.uint8), "name": "a"}])[0]["max_logit"]
    mapped = Scorer(network, PredictSettings(methods=("max_logit",), unit_interval=(-3.0, 2.0)))(
        [{"input": np.zeros((6, 7, 3), np.uint8), "name": "a"}])[0]["max_logit"]
    np.testing.assert_allclose(np.asarray(plain), -logits.max(-1), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(mapped), 1 / (1 + np.exp(-(-logits.max(-1) + 3.0) / 2.0)), rtol=1e-5)
    for bad in ((0.0, 0.0), (0.0,), (np.nan, 1.0)):
        with pytest.raises(ValueError, match="unit_interval: expected"):
            PredictSettings(methods=("msp",), unit_interval=bad)


def test_evaluate_maps_refuses_the_other_tracks_maps_and_statistics(tmp_path, capsys):
    """One track's maps scored with the other's component rules, or statistics that cannot change
    finished maps, are one line each, before anything is written."""
    from jaxanom.cli import main

    root = _obstacle_track_and_maps(tmp_path)
    common = ["evaluate", "--maps", str(tmp_path / "pred"), "--dataset", "smiyc", "--path", str(root)]
    stats = tmp_path / "stats.npz"
    stats.write_bytes(b"")  # never read: refused first
    for extra, named in ((["--track", "anomaly"], ["--maps: ", "ObstacleTrack-all holds the obstacle track's maps",
                                                   "--track anomaly would score", "pass --track obstacle"]),
                         (["--track", "obstacle", "--stats", str(stats)],
                          [f"--stats {stats}: --maps reads finished score maps"])):
        out = tmp_path / "o"
        assert main([*common, *extra, "--out", str(out)]) == 2
        error = capsys.readouterr().err.strip()
        assert len(error.splitlines()) == 1 and all(part in error for part in named), error
        assert not out.exists()
    (tmp_path / "pred" / "anomaly_p" / "synthetic" / "ObstacleTrack-all").rename(
        tmp_path / "pred" / "anomaly_p" / "synthetic" / "AnomalyTrack-all")
    assert main([*common, "--track", "obstacle", "--out", str(tmp_path / "o")]) == 2
    assert "AnomalyTrack-all holds the anomaly track's maps" in capsys.readouterr().err
    assert main([*common, "--track", "none", "--out", str(tmp_path / "o")]) == 0  # pixel metrics only: no rules
