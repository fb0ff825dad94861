"""CuDAM's attention upsampling and ensemble score (Eq. 10) against NumPy references."""
import numpy as np
import pytest

from jaxanom.cudam.score import cudam_score, upsample_attention


def ref_bilinear(image, out_h, out_w):
    """Half-pixel-centre bilinear resize of (..., h, w), edges clamped (PyTorch align_corners=False)."""
    h, w = image.shape[-2:]

    def taps(n_out, n_in):
        src = np.clip((np.arange(n_out) + 0.5) * n_in / n_out - 0.5, 0, n_in - 1)
        lo = np.floor(src).astype(int)
        hi = np.minimum(lo + 1, n_in - 1)
        return lo, hi, src - lo

    r0, r1, fr = taps(out_h, h)
    c0, c1, fc = taps(out_w, w)
    x = image.astype(np.float64)
    rows = x[..., r0, :] * (1 - fr)[:, None] + x[..., r1, :] * fr[:, None]
    return rows[..., c0] * (1 - fc) + rows[..., c1] * fc


@pytest.mark.parametrize("shape, size", [((3, 4), (12, 16)), ((2, 5, 3), (17, 7)), ((1, 1), (4, 6))])
def test_upsample_attention_matches_bilinear_reference(shape, size):
    attention = np.random.default_rng(0).random(shape).astype(np.float32)
    got = upsample_attention(attention, size)
    assert got.shape == shape[:-2] + size and got.dtype == np.float32
    np.testing.assert_allclose(got, ref_bilinear(attention, *size), rtol=1e-5, atol=1e-7)


def test_cudam_score_is_eq10_in_float32():
    rng = np.random.default_rng(1)
    score = rng.normal(size=(2, 9, 11)).astype(np.float32)
    z = rng.normal(size=(2, 3, 4))
    attention = np.exp(z) / np.exp(z).sum(axis=(1, 2), keepdims=True)  # sums to 1 per image
    attention_up = ref_bilinear(attention, 9, 11).astype(np.float32)
    for got, k, up, sigma in ((cudam_score(score, attention_up), score, attention_up, 2e4),
                              (cudam_score(score[0], attention_up[0], sigma=3.0), score[0], attention_up[0], 3.0)):
        k, term = k.astype(np.float64), sigma * up.astype(np.float64)
        # Float32 bound: the product and the sum rounded once each (no fused multiply-add
        # assumed), relative to the terms, since the sum may nearly cancel.
        bound = np.finfo(np.float32).eps * (np.abs(k) + np.abs(term))
        assert got.dtype == np.float32
        assert (np.abs(np.asarray(got, np.float64) - (k + term)) <= bound).all()


def test_bad_shapes_raise_value_error():
    with pytest.raises(ValueError, match="attention_up"):
        cudam_score(np.zeros((4, 4)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="attention"):
        upsample_attention(np.zeros(4), (8, 8))


def test_equivalent_weight_keeps_weight_times_attention():
    from jaxanom.cudam.score import PAPER_TRAIN_POSITIONS, equivalent_weight

    assert PAPER_TRAIN_POSITIONS == 180 * 180
    # A uniform map of n positions has values 1/n: the product with the weight must not change.
    paper = 5e4 * (1 / PAPER_TRAIN_POSITIONS)
    for positions in (1, 2048, 36864, 131072):
        assert equivalent_weight(5e4, positions, PAPER_TRAIN_POSITIONS) * (1 / positions) == pytest.approx(paper)
    with pytest.raises(ValueError, match="positions"):
        equivalent_weight(5e4, 0, PAPER_TRAIN_POSITIONS)
