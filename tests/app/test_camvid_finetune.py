"""Fine-tuning a converted run on CamVid (a tiny folder in its real layout): the new head, the run
the other commands read, and the layers that depend on the class count."""
import json
import types

import jax
import numpy as np
import pytest

from camvid_tree import write_camvid
import converted_run
from jaxanom.app.experiment import class_layers, load_experiment, load_variables
from jaxanom.app.runs import write_run
from jaxanom.cli import main
from jaxanom.models import build_model

tiny_run = converted_run.tiny_run  # a module-scoped fixture: a converted tiny DeepLabV3+, 19 classes


def _shapes(name, classes):
    model = build_model(name, num_classes=classes)
    return jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), np.zeros((1, 32, 32, 3), np.float32))


@pytest.mark.parametrize("name, layers", [
    ("erfnet", ("decoder/output_conv",)),
    ("deeplabv3plus_tiny", ("classifier",)),
    # ESPNet's decoder is as wide as the class count: all of it but nothing of the encoder's trunk
    ("espnet_p2_q8", ("br", "classifier", "combine_act", "combine_bn", "combine_esp/act", "combine_esp/bn",
                      "combine_esp/c1", "combine_esp/d1", "combine_esp/d16", "combine_esp/d2", "combine_esp/d4",
                      "combine_esp/d8", "conv", "conv_act", "conv_bn", "encoder/classifier", "level3_C", "up_l2",
                      "up_l2_act", "up_l2_bn", "up_l3")),
])
def test_class_layers_are_what_depends_on_the_class_count(name, layers):
    assert class_layers(_shapes(name, 11), _shapes(name, 20)) == layers
    assert class_layers(_shapes(name, 11), _shapes(name, 11)) == ()


@pytest.fixture
def camvid(tmp_path):
    write_camvid(tmp_path / "CamVid", 32, 48)
    return tmp_path / "CamVid"


def _train(camvid, init_from, run, *more):
    return main(["train", "--data", "camvid", "--data-root", str(camvid), "--init-from", str(init_from), "--steps", "2",
                 "--batch-size", "4", "--set", "crop=16,32", "--out", str(run), "--no-progress", *more])


def test_train_on_camvid_from_a_converted_run_starts_with_a_new_head(tiny_run, camvid, tmp_path, monkeypatch):
    started = {}

    def train(config, model, batches, val, variables=None):  # the loop itself is tested elsewhere
        started.update(model=model, batch=next(iter(batches)), val=val, variables=variables)
        return types.SimpleNamespace(variables=variables)

    monkeypatch.setattr("jaxanom.train.segmenter.train", train)
    assert _train(camvid, tiny_run, tmp_path / "run") == 0
    experiment = load_experiment(tmp_path / "run")
    assert (experiment.model, experiment.num_classes, experiment.data) == ("deeplabv3plus_tiny", 11, "camvid")
    assert experiment.init_modules is None and started["model"].num_classes == 11
    assert started["batch"]["image"].shape == (4, 16, 32, 3)  # augmented crops of the training frames
    # the whole val split (2 frames here), whole frames
    assert [batch["image"].shape for batch in started["val"]] == [(2, 32, 48, 3)] and "label" in started["val"][0]
    # every module of the converted run but its classifier, which starts from the seed
    _, source = load_variables(tiny_run)
    fresh = jax.jit(started["model"].init, static_argnames="train")(
        jax.random.key(experiment.train.seed), np.zeros((1, *experiment.crop, 3), np.float32), train=False)
    for path, leaf in jax.tree_util.tree_leaves_with_path(started["variables"]):
        keys = tuple(k.key for k in path)
        want = fresh if keys[1] == "classifier" else source
        np.testing.assert_array_equal(leaf, _at(want, keys), err_msg=jax.tree_util.keystr(path))


def test_a_bad_camvid_list_is_one_line_naming_the_data_root(camvid, tmp_path, capsys):
    (camvid / "train.txt").write_text("/SegNet/CamVid/train/a.png /SegNet/CamVid/testannot/a.png\n")
    assert main(["train", "--data", "camvid", "--data-root", str(camvid), "--out", str(tmp_path / "run")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("jaxanom train: error: --data-root: line 1 of ") and len(error.splitlines()) == 1, error
    assert not (tmp_path / "run").exists()  # nothing blocks a rerun


def test_the_data_gives_the_classes_unless_the_run_has_them(camvid, tmp_path, monkeypatch):
    monkeypatch.setattr("jaxanom.train.segmenter.train", lambda config, model, batches, val, variables=None:
                        types.SimpleNamespace(variables=variables))
    assert main(["train", "--data", "camvid", "--data-root", str(camvid), "--steps", "1", "--batch-size", "4",
                 "--set", "crop=16,32", "--out", str(tmp_path / "fresh"), "--no-progress"]) == 0
    assert load_experiment(tmp_path / "fresh").num_classes == 11
    # a network with the data's 19 classes and a void output (ESPNet's, ERFNet's) keeps its 20
    model = build_model("deeplabv3plus_tiny", num_classes=20)
    write_run(tmp_path / "void", "deeplabv3plus_tiny", model,
              jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), _shapes("deeplabv3plus_tiny", 20)))
    assert main(["train", "--data", "synthetic", "--init-from", str(tmp_path / "void"), "--steps", "1",
                 "--batch-size", "4", "--out", str(tmp_path / "kept"), "--no-progress"]) == 0
    assert load_experiment(tmp_path / "kept").num_classes == 20


@pytest.mark.end_to_end
def test_a_camvid_run_is_validated_and_read_by_every_command(tiny_run, camvid, tmp_path):
    run = tmp_path / "run"
    assert _train(camvid, tiny_run, run) == 0
    logged = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert any("val/miou" in line for line in logged)  # validated on the CamVid val frames at the last step
    stats = tmp_path / "stats.npz"
    assert main(["fit-stats", "--run", str(run), "--frames", "4", "--missing", "pooled", "--out", str(stats)]) == 0
    with np.load(stats) as data:
        assert data["mean"].shape == (11,)
    maps = tmp_path / "maps"
    assert main(["predict", str(camvid / "test"), "--run", str(run), "--stats", str(stats), "--methods", "msp,sml_post",
                 "--format", "npy", "--out", str(maps), "--no-progress"]) == 0
    assert np.load(maps / "npy" / "sml_post" / "Seq05VD_f05100.npy").shape == (32, 48)
    out = tmp_path / "eval"
    assert main(["evaluate", "--run", str(run), "--dataset", "synthetic", "--path", "anomaly", "--frames", "2",
                 "--stats", str(stats), "--methods", "msp,sml_post", "--out", str(out), "--pictures", "1"]) == 0
    assert set(json.loads((out / "metrics.json").read_text())["metrics"]) == {"msp", "sml_post"}


def _at(tree, keys):
    for key in keys:
        tree = tree[key]
    return np.asarray(tree)
