"""The scores of experiments/real_training_claims.py against NumPy / PyTorch / OpenCV renderings of the
equations: the logit-scale control's logits, CuDAM's ensemble (Eq. 10) with the paper-equivalent
sigma, the oracle attention, each map resized back to the label's size."""
import cv2
import numpy as np
import pytest
import torch

from experiments import real_training_claims as claims

C = 11


def softmax(x):
    e = np.exp(x - x.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def test_the_controls_logits_are_scaled_by_their_predicted_classs_factor():
    logits = np.random.default_rng(0).normal(size=(2, 5, 7, C)).astype(np.float32)
    factors = np.geomspace(0.25, 4.0, C)
    out = claims.scaled(logits)
    for index in np.ndindex(logits.shape[:3]):
        np.testing.assert_allclose(out[index], logits[index] * factors[logits[index].argmax()], rtol=1e-6)


def test_the_frame_scores_follow_eq_10_and_are_resized_to_the_label():
    rng = np.random.default_rng(1)
    h, w, H, W = 3, 4, 24, 32  # the attention map at 1/8 of the logits
    logits = rng.normal(size=(1, H, W, C)).astype(np.float32) * 3
    attention = softmax(rng.normal(size=(1, h * w))).reshape(1, h, w).astype(np.float32)
    label = np.zeros((45, 61), np.uint8)  # the frame's own size, not a multiple of the logits'
    label[10:20, 5:30], label[:3] = 1, 255
    mean, std = rng.normal(size=C).astype(np.float32), rng.uniform(0.5, 2, C).astype(np.float32)
    stats = (mean, std)
    scores = claims.frame_scores({"logits": logits, "attention": attention}, stats, stats, label)

    def back(x):
        return cv2.resize(np.asarray(x, np.float32), (61, 45), interpolation=cv2.INTER_LINEAR)

    msp = 1 - softmax(logits[0]).max(-1)
    up = torch.nn.functional.interpolate(torch.from_numpy(attention)[None], size=(H, W), mode="bilinear",
                                         align_corners=False)[0, 0].numpy()
    sigma = 2e4 * (h * w) / (256 * 512)
    np.testing.assert_allclose(scores["msp"], back(msp), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(scores["msp+att"], back(msp + sigma * up), rtol=1e-5, atol=1e-6)
    max_logit = -logits[0].max(-1)  # higher = more anomalous
    np.testing.assert_allclose(scores["max_logit+att"], back(max_logit + sigma * up), rtol=1e-5, atol=1e-5)
    oracle = np.where(label == 1, 1 / ((label == 1).mean() * h * w), 0.0)
    np.testing.assert_allclose(scores["sml_post+oracle"], scores["sml_post"] + sigma * oracle, rtol=1e-5, atol=1e-5)
    predicted = logits[0].argmax(-1)
    sml = -(logits[0].max(-1) - mean[predicted]) / std[predicted]
    scaled_max = -claims.scaled(logits)[0].max(-1)
    np.testing.assert_allclose(scores["scaled_max_logit"], back(scaled_max), rtol=1e-5, atol=1e-5)
    assert set(scores) >= {"entropy", "sml_post", "scaled_sml", "sml_post+att"}
    assert np.corrcoef(back(sml).ravel(), scores["sml_post"].ravel())[0, 1] > 0.5  # post-processed SML


def test_without_attention_there_is_no_ensemble():
    logits = np.random.default_rng(2).normal(size=(1, 16, 16, C)).astype(np.float32)
    stats = (np.zeros(C, np.float32), np.ones(C, np.float32))
    scores = claims.frame_scores({"logits": logits}, stats, stats, np.zeros((16, 16), np.uint8))
    assert not any("+" in name for name in scores)
    with pytest.raises(KeyError):
        scores["sml_post+oracle"]
