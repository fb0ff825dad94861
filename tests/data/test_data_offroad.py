"""Synthetic off-road sequences and the simulated patch annotator."""
import numpy as np
import pytest

from jaxanom.data.offroad import DOMAINS, GRANULARITIES, LV3, OffroadSequence, generate_frame, to_granularity
from jaxanom.data.patch_annotations import annotate, window_counts

H, W = 64, 128


def test_frames_are_pure_functions_of_their_arguments():
    a = generate_frame("A", 1, 7, seed=3, height=H, width=W)
    b = generate_frame("A", 1, 7, seed=3, height=H, width=W)
    assert a["image"].tobytes() == b["image"].tobytes() and a["label"].tobytes() == b["label"].tobytes()
    for other in (generate_frame("A", 1, 7, seed=4, height=H, width=W), generate_frame("A", 2, 7, seed=3, height=H, width=W),
                  generate_frame("C", 1, 7, seed=3, height=H, width=W), generate_frame("A", 1, 8, seed=3, height=H, width=W)):
        assert other["image"].tobytes() != a["image"].tobytes()


def test_consecutive_frames_are_near_duplicates_and_distant_ones_are_not():
    seq = OffroadSequence("A", 0, 40, height=H, width=W)
    near = [np.mean(seq[i]["label"] == seq[i + 1]["label"]) for i in range(0, 30, 6)]
    far = [np.mean(seq[i]["label"] == seq[i + 30]["label"]) for i in range(0, 10, 3)]
    assert min(near) > 0.85
    assert max(far) < min(near)
    diff = lambda i, j: np.abs(seq[i]["image"].astype(int) - seq[j]["image"].astype(int)).mean()  # noqa: E731
    assert diff(5, 6) < diff(5, 35)


@pytest.mark.parametrize("domain", sorted(DOMAINS))
def test_every_domain_renders_valid_labels_and_the_shifted_domains_look_different(domain):
    frame = generate_frame(domain, 0, 0, height=H, width=W)
    assert frame["image"].shape == (H, W, 3) and frame["image"].dtype == np.uint8
    assert frame["label"].shape == (H, W) and frame["label"].max() < len(LV3)
    assert {LV3.index("sky"), LV3.index("grass")} <= set(np.unique(frame["label"]).tolist())


def test_domain_shift_changes_the_colour_of_a_class():
    def mean_colour(domain, cls):
        pixels = [f["image"][f["label"] == cls] for f in (generate_frame(domain, s, 0, height=H, width=W) for s in range(3))]
        return np.concatenate(pixels).mean(0)
    grass = LV3.index("grass")
    assert np.abs(mean_colour("A", grass) - mean_colour("B", grass)).max() > 20
    assert np.abs(mean_colour("B", grass) - mean_colour("C", grass)).max() < 10


def test_granularities_are_a_hierarchy():
    lv3 = np.arange(10)
    lv2, lv1 = to_granularity(lv3, "lv2"), to_granularity(lv3, "lv1")
    assert len(np.unique(lv2)) == 6 and len(np.unique(lv1)) == 4
    assert len(np.unique(to_granularity(lv3, "deepscene"))) == 5
    for coarse in np.unique(lv2):  # every lv2 class lies inside one lv1 class
        assert len(np.unique(lv1[lv2 == coarse])) == 1
    assert to_granularity(np.array([255]), "lv1")[0] == 255
    names = GRANULARITIES["deepscene"][0]
    ds = to_granularity(lv3, "deepscene")
    assert names[ds[LV3.index("log")]] == "obstacle" and names[ds[LV3.index("gravel")]] == "trail"
    with pytest.raises(ValueError, match="granularity"):
        to_granularity(lv3, "lv4")


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="domain"):
        generate_frame("F", 0, 0)
    with pytest.raises(ValueError, match="index"):
        generate_frame("A", 0, -1)
    with pytest.raises(IndexError):
        OffroadSequence("A", 0, 3, height=H, width=W)[3]


def test_window_counts_match_numpy_crops():
    rng = np.random.default_rng(0)
    label = rng.integers(0, 4, (13, 17)).astype(np.uint8)
    label[2, 3] = 255
    counts = window_counts(label, 4, 5)
    assert counts.shape == (9, 13, 4)
    for r, c in [(0, 0), (8, 12), (3, 7)]:
        crop = label[r:r + 5, c:c + 5]
        assert counts[r, c].tolist() == [int((crop == k).sum()) for k in range(4)]


def test_annotations_are_pure_windows_with_per_image_renumbered_ids():
    frame = generate_frame("A", 0, 3)
    seen = set()
    for seed in range(4):
        ann = annotate(frame["label"], np.random.default_rng(seed), k=12, size=32)
        assert len(ann["ids"]) == 12
        for (r, c), ref in zip(ann["centers"], ann["reference"]):
            crop = frame["label"][r - 16:r + 16, c - 16:c + 16]
            assert crop.shape == (32, 32) and np.mean(crop == ref) >= 0.9
        present = np.unique(ann["reference"])
        assert sorted(np.unique(ann["ids"]).tolist()) == list(range(len(present)))
        for ref in present:  # one id per class, one class per id
            assert len(np.unique(ann["ids"][ann["reference"] == ref])) == 1
        seen.add(tuple(ann["ids"][np.searchsorted(ann["reference"], present, sorter=np.argsort(ann["reference"]))]))
    assert len(seen) > 1  # the numbering changes from annotation to annotation
    # round-robin: with k = the number of classes having a pure window, each gets exactly one
    pure = (window_counts(frame["label"], 10, 32)[::4, ::4] >= 0.9 * 32 * 32).any((0, 1))
    ann = annotate(frame["label"], np.random.default_rng(0), k=int(pure.sum()), size=32)
    assert sorted(ann["reference"].tolist()) == np.flatnonzero(pure).tolist()


def test_annotating_a_single_class_or_void_frame():
    one = annotate(np.full((40, 40), 4, np.uint8), np.random.default_rng(0), k=5, size=16)
    assert one["reference"].tolist() == [4] * 5 and one["ids"].tolist() == [0] * 5
    void = annotate(np.full((40, 40), 255, np.uint8), np.random.default_rng(0), k=5, size=16)
    assert void["centers"].shape == (0, 2) and void["ids"].shape == (0,)
    with pytest.raises(ValueError, match="label"):
        annotate(np.zeros((8, 8), np.uint8), np.random.default_rng(0), size=16)
