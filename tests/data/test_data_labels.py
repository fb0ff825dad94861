"""The Cityscapes label table against facts of the official definition, written out here."""
import numpy as np

from jaxanom.data.cityscapes_labels import CLASS_COLORS, CLASS_NAMES, LABEL_ID_TO_TRAIN_ID, NUM_CLASSES
from jaxanom.viz import colorize


def test_label_ids_map_to_the_official_train_ids():
    official = {7: 0, 8: 1, 11: 2, 12: 3, 13: 4, 17: 5, 19: 6, 20: 7, 21: 8, 22: 9, 23: 10, 24: 11,
                25: 12, 26: 13, 27: 14, 28: 15, 31: 16, 32: 17, 33: 18}
    for label_id in range(256):
        assert LABEL_ID_TO_TRAIN_ID[label_id] == official.get(label_id, 255), label_id
    assert LABEL_ID_TO_TRAIN_ID.dtype == np.uint8


def test_names_and_colours_of_the_19_classes():
    assert NUM_CLASSES == len(CLASS_NAMES) == len(CLASS_COLORS) == 19
    assert CLASS_NAMES[0] == "road" and CLASS_NAMES[10] == "sky" and CLASS_NAMES[18] == "bicycle"
    assert CLASS_COLORS.dtype == np.uint8
    assert CLASS_COLORS[0].tolist() == [128, 64, 128]
    assert CLASS_COLORS[10].tolist() == [70, 130, 180]
    assert CLASS_COLORS[13].tolist() == [0, 0, 142]
    assert len({tuple(c) for c in CLASS_COLORS.tolist()}) == 19


def test_the_palette_paints_train_ids_and_blacks_out_ignore():
    train_ids = np.array([[0, 13], [255, 18]], np.uint8)
    out = colorize(train_ids, CLASS_COLORS)
    assert out.shape == (2, 2, 3) and out.dtype == np.uint8
    assert out[0, 0].tolist() == [128, 64, 128] and out[0, 1].tolist() == [0, 0, 142]
    assert out[1, 0].tolist() == [0, 0, 0] and out[1, 1].tolist() == [119, 11, 32]
