"""The frozen-encoder regime of experiments/real_training_common.py on the tiny CamVid fixture and a
random ERFNet: cached features are the encoder's output and a rerun computes none; the crops pair
feature cells with the label pixels under them; ENet's class weights; the written run is the
whole ERFNet (frozen encoder + trained decoder)."""
import jax
import numpy as np
import pytest

from camvid_tree import write_camvid
from experiments import real_training_common as rtc
from jaxanom.app.experiment import trained_steps, build_network, load_variables
from jaxanom.app.runs import write_run
from jaxanom.models.erfnet import ERFNet, normalize_erfnet

H, W = 32, 48


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    """The fixture as CamVid, a random 20-output ERFNet as the Cityscapes one, the cache in tmp_path."""
    write_camvid(tmp_path / "CamVid", H, W)
    model = ERFNet(num_classes=20)
    variables = jax.device_get(model.init(jax.random.key(1), np.zeros((1, H, W, 3), np.float32)))
    rng = np.random.default_rng(0)  # BN statistics that are not the identity, and leave features alive after ReLU

    def statistic(path, x):
        name = path[-1].key
        values = rng.normal(0, 0.1, x.shape) if name == "mean" else rng.random(x.shape) + 0.5
        return values.astype(np.float32)

    variables["batch_stats"] = jax.tree_util.tree_map_with_path(statistic, variables["batch_stats"])
    monkeypatch.setattr(rtc, "CAMVID", tmp_path / "CamVid")
    monkeypatch.setattr(rtc, "CACHE", tmp_path / "cache")
    monkeypatch.setattr(rtc, "cityscapes_erfnet", lambda: (model, variables, "digest"))
    return model, variables


def test_cached_features_are_the_encoders_and_a_rerun_computes_none(tiny, monkeypatch):
    model, variables = tiny
    features, labels, _ = rtc.cache_features("train", flip=True, log=lambda *_: None)
    frames = rtc.camvid("train")
    images = np.stack([frames[i]["image"][:, ::-1] for i in range(len(frames))])
    encoder = rtc.encoder_module().apply({c: {"encoder": t["encoder"]} for c, t in variables.items()},
                                         normalize_erfnet(images))
    np.testing.assert_allclose(features, encoder, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(labels, np.stack([frames[i]["label"][:, ::-1] for i in range(len(frames))]))
    assert rtc.cache_folder("train", True) != rtc.cache_folder("train", False)
    monkeypatch.setattr(rtc, "encoder_module", lambda: pytest.fail("a cached frame was computed again"))
    again, _, _ = rtc.cache_features("train", flip=True)
    np.testing.assert_array_equal(again, features)


def test_a_crop_pairs_each_feature_cell_with_the_label_pixels_under_it():
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 11, (5, 8 * 6, 8 * 7)).astype(np.uint8)
    features = np.repeat(labels[:, ::8, ::8, None], 3, -1).astype(np.float32)  # cell value = its top-left label
    settings = rtc.Settings(batch_size=3, crop=(4, 5))
    batch = rtc.crops(features, labels, settings, 7)
    assert batch["image"].shape == (3, 4, 5, 3) and batch["label"].shape == (3, 32, 40)
    np.testing.assert_array_equal(batch["image"][..., 0], batch["label"][:, ::8, ::8])
    np.testing.assert_array_equal(rtc.crops(features, labels, settings, 7)["label"], batch["label"])  # resumable


def test_enet_class_weights_from_the_formula():
    labels = np.array([0, 0, 0, 1, 255, 255, 2, 2])
    p = np.array([3, 1, 2, 0]) / 6
    assert rtc.enet_class_weights(labels, 4) == pytest.approx(1 / np.log(1.02 + p), rel=1e-12)


def test_the_written_run_is_the_frozen_encoder_and_the_decoder(tiny, tmp_path):
    model, variables = tiny
    decoder = rtc.decoder_module(11)
    example = np.zeros((1, H // 8, W // 8, 128), np.float32)
    trained = jax.device_get(decoder.init(jax.random.key(2), example))
    whole = {c: {**rtc.encoder_variables()[c], **trained[c]} for c in trained}
    write_run(tmp_path / "run", "erfnet", ERFNet(num_classes=11), whole, 7, data="camvid", data_root="x", crop=(H, W))
    experiment, stored = load_variables(tmp_path / "run")
    assert (experiment.data, experiment.num_classes) == ("camvid", 11)
    assert trained_steps(tmp_path / "run") == 7  # a trained network: fit-stats reads its training frames
    images = np.random.default_rng(1).integers(0, 256, (2, H, W, 3), np.uint8)
    logits = build_network(experiment).apply(stored, normalize_erfnet(images))["logits"]
    encoded = rtc.encoder_module().apply(rtc.encoder_variables(), normalize_erfnet(images))
    np.testing.assert_allclose(logits, decoder.apply(trained, encoded)["logits"], rtol=1e-5, atol=1e-5)


def test_a_crop_cuts_each_tap_at_its_own_scale():
    rng = np.random.default_rng(1)
    labels = rng.integers(0, 11, (4, 8 * 6, 8 * 7)).astype(np.uint8)
    features = labels[:, ::8, ::8, None].astype(np.float32)
    taps = {"low": labels[:, ::4, ::4, None].astype(np.float32), "mid": features.copy()}
    settings = rtc.Settings(batch_size=2, crop=(3, 4))
    batch = rtc.crops(features, labels, settings, 3, taps)
    assert batch["low"].shape == (2, 6, 8, 1) and batch["mid"].shape == (2, 3, 4, 1)
    np.testing.assert_array_equal(batch["low"][..., 0], batch["label"][:, ::4, ::4])
    np.testing.assert_array_equal(batch["mid"], batch["image"])


def test_the_baselines_run_key_leaves_out_the_later_fields_at_their_defaults(tiny):
    old = {"seed": 0, "steps": 1000, "batch_size": 8, "crop": [24, 32], "optimizer": "adamw", "lr": 5e-4,
           "weight_decay": 1e-4, "class_weights": "enet", "num_classes": 11}  # the fields of the first networks
    key = rtc.settings_key({**old, "weights": "digest", "train": rtc.cache_folder("train", False).name,
                            "version": rtc.CACHE_VERSION})
    assert rtc.run_folder(rtc.Settings()).name == f"decoder-{key}"
    assert rtc.run_folder(rtc.Settings(attention="cudam")) != rtc.run_folder(rtc.Settings())
    assert rtc.run_folder(rtc.Settings(attention="cudam", objective=(("beta", 0.0),))) != \
        rtc.run_folder(rtc.Settings(attention="cudam"))


def test_a_run_with_attention_is_the_encoder_its_taps_the_module_and_the_decoder(tiny, tmp_path):
    """The decoder trained with CuDAM on cached features and taps, written as one ERFNet, gives the
    logits and attention map of encoder -> module -> decoder (what evaluate --run reads)."""
    settings = rtc.Settings(attention="cudam")
    decoder = rtc.decoder_module(11, "cudam")
    images = np.random.default_rng(2).integers(0, 256, (2, H, W, 3), np.uint8)
    encoded, taps = rtc.encoder_module(with_taps=True).apply(rtc.encoder_variables(), normalize_erfnet(images))
    trained = jax.device_get(decoder.init(jax.random.key(3), encoded, low=taps["low"], mid=taps["mid"]))
    trained["params"]["cudam"]["alpha"] = np.float32(0.7)  # a module that changes the features
    whole = {c: {**rtc.encoder_variables()[c], **trained[c]} for c in trained}
    write_run(tmp_path / "run", "erfnet", ERFNet(num_classes=11, attention="cudam"), whole, 7, data="camvid",
              data_root="x", crop=(H, W))
    experiment, stored = load_variables(tmp_path / "run")
    assert experiment.attention == "cudam"
    out = build_network(experiment).apply(stored, normalize_erfnet(images))
    (ours,) = list(rtc.decoder_outputs(trained, settings, np.asarray(encoded), jax.device_get(taps)))
    np.testing.assert_allclose(out["logits"], ours["logits"], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(out["attention"], ours["attention"], rtol=1e-5, atol=1e-8)


def test_the_attention_modules_objective_takes_the_settings_options():
    from jaxanom.cudam.objective import CuDAM
    from jaxanom.losses import CrossEntropy
    from jaxanom.msaam.objective import MSAAM

    weights = (1.0, 2.0)
    assert rtc.objective_of(rtc.Settings(), weights) == CrossEntropy(weights)
    assert rtc.objective_of(rtc.Settings(attention="cudam", objective=(("reward_prob", 0.0), ("beta", 0.0))),
                            weights) == CuDAM(reward_prob=0.0, beta=0.0, class_weights=weights)
    assert rtc.objective_of(rtc.Settings(attention="msaam"), weights) == MSAAM(class_weights=weights)
