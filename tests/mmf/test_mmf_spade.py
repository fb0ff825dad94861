"""MMF's SPADE synthesizer (docs/papers/mmf.md#spade-generator): losses against NumPy, the networks, the GAN loop, the pipeline option.

Every network here has one tiny size, that of ``MMFConfig.quick()`` with the ``gan_*`` settings
below, so that the GAN step compiles once for the whole file.
"""
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.data.synthetic import SyntheticScenes
from jaxanom.mmf.gan import (feature_matching_loss, generator_loss, hinge_discriminator_loss, hinge_generator_loss,
                             l1_loss)
from jaxanom.mmf import gan_train
from jaxanom.mmf.gan_train import GANConfig, init_gan_state, train_gan, trained_generator
from jaxanom.app.mmf_pipeline import MMFConfig, _gan_config, build_synthesizer, load_synthesizer
from jaxanom.mmf.synthesis import ClassMeanSynthesizer, SPADESynthesizer, resynthesize
from jaxanom.models.patch_discriminator import MultiscaleDiscriminator
from jaxanom.models.spade_generator import SPADEGenerator
from compiles import compiled_during
from host_reads import count_host_reads

PIPELINE = dataclasses.replace(MMFConfig.quick(), synthesizer="spade", gan_steps=2, gan_nf=4, gan_upsamples=2,
                               gan_hidden=8, gan_layers=2)
CLASSES, B = PIPELINE.segmenter.num_classes, PIPELINE.batch_size
H, W = PIPELINE.segmenter.height, PIPELINE.segmenter.width
GENERATOR = SPADEGenerator(CLASSES, PIPELINE.gan_nf, PIPELINE.gan_upsamples, PIPELINE.gan_hidden)
CRITIC = MultiscaleDiscriminator(CLASSES, PIPELINE.gan_nf, PIPELINE.gan_layers)


def _awkward(rng, shape):
    """Logits with exact hinge corners (+-1, 0), huge magnitudes and ordinary values."""
    values = rng.normal(0, 2, shape)
    flat = values.reshape(-1)
    flat[:6] = [1.0, -1.0, 0.0, 1e6, -1e6, 1 - 1e-7][:flat.size]
    return values.astype(np.float32)


def test_hinge_losses_match_numpy():
    rng = np.random.default_rng(0)
    shapes = [(3, 5, 7, 1), (3, 2, 3, 1)]  # two scales, odd sizes
    real, fake = [_awkward(rng, s) for s in shapes], [_awkward(rng, s)[::-1].copy() for s in shapes]
    expect_d = np.mean([np.mean(np.maximum(0, 1 - r.astype(np.float64)))
                        + np.mean(np.maximum(0, 1 + f.astype(np.float64))) for r, f in zip(real, fake)])
    expect_g = np.mean([-np.mean(f.astype(np.float64)) for f in fake])
    np.testing.assert_allclose(float(hinge_discriminator_loss(real, fake)), expect_d, rtol=1e-5)
    # -mean D(fake) sums +-1e6 in float32: absolute error ~ float32 epsilon * 1e6 / size
    np.testing.assert_allclose(float(hinge_generator_loss(fake)), expect_g, rtol=1e-5, atol=1e-3)
    # one scale, every logit inside the margin: D loss is 2 exactly
    np.testing.assert_allclose(float(hinge_discriminator_loss([np.zeros((1, 1))], [np.zeros((1, 1))])), 2.0)


def test_feature_matching_and_l1_match_numpy():
    rng = np.random.default_rng(1)
    shapes = [[(2, 5, 9, 4), (2, 6, 10, 8)], [(2, 3, 5, 4), (2, 4, 6, 8), (2, 1, 1, 1)]]
    real = [[rng.normal(0, 1, s).astype(np.float32) for s in scale] for scale in shapes]
    fake = [[(rng.normal(0, 1, s) * 1e4).astype(np.float32) for s in scale] for scale in shapes]
    fake[0][0][:] = real[0][0]  # an identical layer contributes 0
    layers = [np.mean(np.abs(r.astype(np.float64) - f)) for rs, fs in zip(real, fake) for r, f in zip(rs, fs)]
    np.testing.assert_allclose(float(feature_matching_loss(real, fake)), np.mean(layers), rtol=1e-5)
    x, y = rng.random((2, 7, 5, 3)).astype(np.float32), rng.random((2, 7, 5, 3)).astype(np.float32)
    np.testing.assert_allclose(float(l1_loss(x, y)), np.mean(np.abs(x.astype(np.float64) - y)), rtol=1e-6)
    logits = [rng.normal(0, 1, (2, 3, 3, 1)).astype(np.float32)]
    total, parts = generator_loss(logits, real, fake, x, y)  # the weights of docs/papers/mmf.md#spade-generator: hinge + 10 FM + 10 L1
    np.testing.assert_allclose(float(total), -np.mean(logits[0]) + 10 * np.mean(layers)
                               + 10 * np.mean(np.abs(x.astype(np.float64) - y)), rtol=1e-5)
    assert set(parts) == {"g_hinge", "feature_matching", "l1"}
    total, _ = generator_loss(logits, real, real, x, y)  # no feature term: the L1 weight shows at full precision
    np.testing.assert_allclose(float(total), -np.mean(logits[0]) + 10 * np.mean(np.abs(x.astype(np.float64) - y)),
                               rtol=1e-6)
    total, _ = generator_loss(logits, real, fake, x, y, feature_weight=2.0, l1_weight=0.5)
    np.testing.assert_allclose(float(total), -np.mean(logits[0]) + 2 * np.mean(layers)
                               + 0.5 * np.mean(np.abs(x.astype(np.float64) - y)), rtol=1e-5)
    # scales or layers that do not pair up are an error, not silently truncated
    with pytest.raises(ValueError, match="zip"):
        feature_matching_loss(real, fake[:1])
    with pytest.raises(ValueError, match="zip"):
        feature_matching_loss([real[0]], [fake[0][:1]])
    with pytest.raises(ValueError, match="zip"):
        hinge_discriminator_loss(logits * 2, logits)
    # the real features are targets: no gradient flows into them
    grad = jax.grad(lambda r: feature_matching_loss([[r]], [[jnp.zeros_like(r)]]))(jnp.ones((2, 3)))
    assert not np.any(np.asarray(grad))


def _batch(seed=0):
    rng = np.random.default_rng(seed)
    semantic = rng.integers(0, CLASSES, (B, H, W)).astype(np.int32)
    semantic[:, : H // 2] = semantic[:, :1]  # blocky upper half
    semantic[0, -3:] = 255  # unknown pixels
    image = rng.integers(0, 256, (B, H, W, 3), dtype=np.uint8)
    return {"image": image, "label": semantic}


@pytest.fixture(scope="module")
def state():
    return init_gan_state(GANConfig("unused"), GENERATOR, CRITIC, _batch())


def test_generator_output_shape_range_and_unknown_label(state):
    semantic = _batch()["label"]
    r = np.asarray(SPADESynthesizer(GENERATOR, state.generator_variables).synthesize_batch(semantic))
    assert r.shape == (B, H, W, 3) and r.dtype == np.float32
    assert np.all(np.isfinite(r)) and r.min() >= 0.0 and r.max() <= 1.0
    # the pipeline's jitted maps call resynthesize: the generator, or the class-mean gather
    inside = jax.jit(resynthesize, static_argnums=0)
    np.testing.assert_allclose(np.asarray(inside(GENERATOR, state.generator_variables, semantic)), r, atol=1e-6)
    means = ClassMeanSynthesizer(np.random.default_rng(0).random((CLASSES + 1, 3)).astype(np.float32))
    np.testing.assert_array_equal(np.asarray(inside(None, means.arrays, semantic)),
                                  np.asarray(means.synthesize_batch(semantic)))


def test_discriminator_scales_and_features(state):
    batch = _batch()
    out = CRITIC.apply({"params": state.d_params}, batch["image"] / 255.0, batch["label"])
    assert len(out["logits"]) == 2 and len(out["features"]) == 2
    assert all(len(f) == PIPELINE.gan_layers for f in out["features"])
    assert all(x.shape[-1] == 1 and x.shape[0] == B for x in out["logits"])
    assert out["logits"][1].shape[1] < out["logits"][0].shape[1]  # the second scale sees a half-size input


@pytest.mark.parametrize("semantic, message", [
    (np.zeros((H, W), np.int32), "semantic must have rank 3"),
    (np.zeros((1, H, W), np.float32), "semantic must hold integer"),
    (np.full((1, H, W), CLASSES, np.int32),
     f"semantic: expected classes in \\[0, {CLASSES}\\) or 255, got \\[{CLASSES}\\]"),
    (np.full((1, H, W), -1, np.int32), "got \\[-1\\]"),
    (np.full((1, H, W), 254, np.int32), "got \\[254\\]"),
    (np.zeros((1, H + 2, W), np.int32), "semantic: expected H and W divisible by 4"),
])
def test_generator_rejects_bad_semantic(semantic, message):
    with pytest.raises(ValueError, match=message):
        GENERATOR.apply({}, semantic)


def test_discriminator_and_loop_reject_bad_input(tmp_path):
    semantic = np.zeros((1, H, W), np.int32)
    with pytest.raises(ValueError, match="image: expected float \\(B, H, W, 3\\)"):
        CRITIC.apply({}, np.zeros((1, H, W), np.float32), semantic)
    with pytest.raises(ValueError, match="semantic: expected shape"):
        CRITIC.apply({}, np.zeros((1, H, W, 3), np.float32), semantic[:, :-1])
    image = np.zeros((1, H, W, 3), np.uint8)
    with pytest.raises(ValueError, match="expected batches as dicts with 'image' and 'label'"):
        train_gan(GANConfig(str(tmp_path)), GENERATOR, CRITIC, [{"image": image}])
    with pytest.raises(ValueError, match=f"batch\\['label'\\]: expected values in \\[0, {CLASSES}\\) or 255"):
        train_gan(GANConfig(str(tmp_path)), GENERATOR, CRITIC, [{"image": image, "label": semantic + CLASSES}])
    with pytest.raises(ValueError, match="semantic: expected H and W divisible by 4"):
        train_gan(GANConfig(str(tmp_path)), GENERATOR, CRITIC, [{"image": image[:, 1:], "label": semantic[:, 1:]}])
    with pytest.raises(ValueError, match="gan_upsamples"):
        dataclasses.replace(PIPELINE, gan_upsamples=6)
    with pytest.raises(ValueError, match="synthesizer: expected one of"):
        dataclasses.replace(PIPELINE, synthesizer="vgg")


def _train(run_dir, steps, batches=None):
    config = GANConfig(str(run_dir), steps=steps, save_every=steps, progress=False)  # one save, at the end
    batches = batches if batches is not None else (_batch(seed) for seed in range(1 << 30))
    return train_gan(config, GENERATOR, CRITIC, batches)


def _changed(before, after):
    pairs = zip(jax.tree.leaves(before), jax.tree.leaves(after))
    return np.mean([not np.array_equal(np.asarray(a), np.asarray(b)) for a, b in pairs])


def test_one_step_updates_both_networks(state, tmp_path):
    after = _train(tmp_path, 1, iter([_batch()]))
    assert int(after.step) == 1
    # conv biases right before a parameter-free BatchNorm get no gradient; everything else moves
    assert _changed(state.g_params, after.g_params) > 0.7
    assert _changed(state.d_params, after.d_params) > 0.7
    assert _changed(state.g_batch_stats, after.g_batch_stats) == 1.0


def test_training_on_one_batch_lowers_l1(tmp_path):
    batch = _batch(3)
    palette = np.random.default_rng(4).integers(0, 256, (256, 3), dtype=np.uint8)
    batch["image"] = palette[batch["label"]]  # one colour per class: learnable from the map
    _train(tmp_path, 30, iter(lambda: batch, None))
    l1 = [json.loads(line)["train/l1"] for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert len(l1) == 30
    # Adam at the paper's G rate 1e-4 moves slowly: ~11% lower after 30 steps on CPU (unchanged
    # parameters, a wrong sign or a detached generator would leave it flat or raise it)
    assert np.mean(l1[-5:]) < 0.95 * l1[0], l1
    assert np.all(np.diff(l1[-10:]) < 0), l1


def test_resumed_training_equals_uninterrupted(tmp_path):
    whole = _train(tmp_path / "whole", 3)
    _train(tmp_path / "split", 2)
    resumed = _train(tmp_path / "split", 3)  # restores step 2, skips the 2 batches used
    assert int(resumed.step) == 3
    gan_train._jitted_init.cache_clear()  # new jitted functions, as in a new process: a call would compile
    gan_train._jitted_step.cache_clear()
    again, compiles = compiled_during(lambda: _train(tmp_path / "split", 3))  # finished: restored into shapes alone
    assert compiles == [], compiles
    for state in (resumed, again):
        for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(state)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_pipeline_trains_and_caches_the_spade_synthesizer(tmp_path):
    seg = PIPELINE.segmenter
    frames = [SyntheticScenes("train", 4, seg.train.seed, height=H, width=W)[i] for i in range(4)]
    first = build_synthesizer(PIPELINE, tmp_path, frames, progress=False)
    assert isinstance(first, SPADESynthesizer) and first.model == GENERATOR
    assert [p.name.split("-")[:2] for p in tmp_path.iterdir()] == [["synthesizer", "spade"]]
    again = build_synthesizer(PIPELINE, tmp_path, frames, progress=False)  # loaded from the checkpoint
    for a, b in zip(jax.tree.leaves(first.variables), jax.tree.leaves(again.variables)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    r = np.asarray(again.synthesize_batch(np.stack([f["label"] for f in frames]).astype(np.int32)))
    assert r.shape == (4, H, W, 3) and 0.0 <= r.min() and r.max() <= 1.0
    tree = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*")}
    loaded = load_synthesizer(PIPELINE, tmp_path)  # read-only (evaluate --mmf)
    for a, b in zip(jax.tree.leaves(first.variables), jax.tree.leaves(loaded.variables)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*")} == tree
    unfinished = dataclasses.replace(_gan_config(PIPELINE, tmp_path, False), steps=3)  # same folder, 2 steps done
    with pytest.raises(ValueError, match="trained 2 of 3 steps"):
        trained_generator(unfinished, GENERATOR, CRITIC, {k: np.stack([f[k] for f in frames]) for k in ("image", "label")})
    with pytest.raises(ValueError, match="checkpoint"):
        load_synthesizer(PIPELINE, tmp_path / "empty")


def test_demo_flag_selects_the_synthesizer(monkeypatch, tmp_path):
    import jaxanom.app.demos.mmf as demo
    from jaxanom.cli import main

    seen = []
    monkeypatch.setattr(demo, "run_mmf_demo", lambda out, config, progress: seen.append(config))
    assert main(["demo", "mmf", "--quick", "--synthesizer", "spade", "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    assert main(["demo", "mmf", "--quick", "--out", str(tmp_path / "b"), "--no-progress"]) == 0
    assert [config.pipeline.synthesizer for config in seen] == ["spade", "class_mean"]


def test_non_finite_loss_stops_training(tmp_path):
    from jaxanom.train.segmenter import NonFiniteLossError

    batch = _batch()
    batch["image"] = np.where(batch["label"][..., None] == 255, np.nan, batch["image"] / 255.0).astype(np.float32)
    with pytest.raises(NonFiniteLossError, match="at step 1: training stopped"):
        _train(tmp_path, 2, iter([batch, batch]))


def numpy_adam(grads, lr, b1, b2, eps=1e-8):
    """Kingma & Ba's Adam with bias correction: the parameter after each gradient of ``grads``."""
    p, m, v = 0.0, 0.0, 0.0
    out = []
    for t, g in enumerate(grads, start=1):
        m, v = b1 * m + (1 - b1) * g, b2 * v + (1 - b2) * g * g
        p -= lr * (m / (1 - b1**t)) / (np.sqrt(v / (1 - b2**t)) + eps)
        out.append(p)
    return out


def test_both_optimizers_are_adam_with_the_configs_rates_and_betas():
    from jaxanom.mmf.gan_train import _optimizers

    config = GANConfig(run_dir="unused", g_lr=0.1, d_lr=0.3, betas=(0.5, 0.6))
    grads = [1.0, -3.0, 0.5]
    for tx, lr in zip(_optimizers(config), (config.g_lr, config.d_lr)):
        p, got = jnp.zeros(()), []
        state = tx.init(p)
        for g in grads:
            update, state = tx.update(jnp.asarray(g, jnp.float32), state)
            p = p + update
            got.append(float(p))
        np.testing.assert_allclose(got, numpy_adam(grads, lr, 0.5, 0.6), rtol=1e-5)


def test_step_losses_are_those_of_separate_critic_calls(state):
    """One step's metrics against the loss formulas in NumPy on the critic applied to the real and
    the generated image separately (its instance norm is per example, so batching them is exact)."""
    from jaxanom.mmf.gan_train import _inputs, compiled_step

    image, semantic = _inputs(_batch())
    # the training's own compiled step (it donates its state: a copy keeps the fixture's)
    _, metrics = compiled_step(GANConfig("unused"), GENERATOR, CRITIC)(jax.tree.map(jnp.copy, state), image, semantic)

    @jax.jit  # one compile, not one per primitive of both networks
    def critic_calls(state, image, semantic):
        (out, _) = GENERATOR.apply({"params": state.g_params, "batch_stats": state.g_batch_stats}, semantic,
                                   train=True, mutable=["batch_stats"])
        return [CRITIC.apply({"params": state.d_params}, x, semantic) for x in (image, out["image"])]

    real, fake = critic_calls(state, image, semantic)
    f64 = lambda x: np.asarray(x, np.float64)  # noqa: E731
    fm = np.mean([np.mean(np.abs(f64(r) - f64(f))) for rs, fs in zip(real["features"], fake["features"])
                  for r, f in zip(rs, fs)])
    d = np.mean([np.mean(np.maximum(0, 1 - f64(r))) + np.mean(np.maximum(0, 1 + f64(f)))
                 for r, f in zip(real["logits"], fake["logits"])])
    g = np.mean([-np.mean(f64(f)) for f in fake["logits"]])
    np.testing.assert_allclose([metrics["feature_matching"], metrics["d_loss"], metrics["g_hinge"]], [fm, d, g],
                               rtol=1e-4, atol=1e-6)
    assert fm > 1e-3  # the features differ: a feature term of zero would show


def test_losses_are_read_on_logging_steps_only(tmp_path, monkeypatch):
    drawn = []

    def batches():
        for seed in range(5):
            drawn.append(seed)
            yield _batch(seed)

    config = GANConfig(str(tmp_path), steps=5, save_every=5, progress=False, log_every=2)
    reads = count_host_reads(monkeypatch, lambda: len(drawn))  # tagged: how many steps were dispatched
    train_gan(config, GENERATOR, CRITIC, batches())
    monkeypatch.undo()
    assert set(reads) == {2, 4, 5}  # logging steps 2 and 4, and the last (with its save)
    lines = (tmp_path / "log.jsonl").read_text().splitlines()
    assert [json.loads(line)["step"] for line in lines] == [1, 2, 3, 4, 5]  # every step still logged
