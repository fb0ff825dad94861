"""convert-weights writes what evaluate --run and train --init-from read; take_modules is strict."""
import dataclasses
import types

import jax
import numpy as np
import pytest
import torch

from jaxanom.cli import main
from jaxanom.app.experiment import initial_variables, load_experiment, load_variables
from jaxanom.models import build_model
from jaxanom.app.runs import write_run
from jaxanom.weights import from_torch, read_vgg, take_modules
from torch_reference import randomize, torchvision_models


def tree_equal(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    jax.tree.map(np.testing.assert_array_equal, a, b)


@pytest.fixture(scope="module")
def tv():
    return torchvision_models()


def test_converted_resnet_is_a_run_folder_with_the_imported_weights(tv, tmp_path):
    net = randomize(tv.resnet18(), seed=4)
    torch.save(net.state_dict(), tmp_path / "r18.pth")
    out = tmp_path / "run"
    assert main(["convert-weights", "--from", "torchvision-resnet18", str(tmp_path / "r18.pth"), str(out),
                 "--num-classes", "7", "--seed", "5"]) == 0
    experiment, variables = load_variables(out)  # what evaluate --run reads
    assert (experiment.model, experiment.num_classes, experiment.attention) == ("deeplabv3plus_r18", 7, None)
    _, want = from_torch(net.state_dict(), "torchvision-resnet18", 7, key=jax.random.key(5))
    tree_equal(variables, want)


def test_converted_vgg_reads_back(tv, tmp_path):
    features = {k: v for k, v in randomize(tv.vgg16(), seed=5).state_dict().items() if k.startswith("features.")}
    torch.save(features, tmp_path / "vgg16.pt")
    assert main(["convert-weights", "--from", "torchvision-vgg16", str(tmp_path / "vgg16.pt"), str(tmp_path / "v")]) == 0
    model, variables = read_vgg(tmp_path / "v")
    want_model, want = from_torch(features, "torchvision-vgg16")
    assert model == want_model
    tree_equal(variables, want)


@pytest.mark.parametrize("args, message", [
    (["--from", "sml-deeplabv3plus"], "does not match sml-deeplabv3plus"),
    (["--from", "torchvision-resnet18", "--num-classes", "0"], "num_classes"),
])
def test_convert_weights_errors_are_one_line(tv, tmp_path, capsys, args, message):
    torch.save(tv.resnet18().state_dict(), tmp_path / "r18.pth")
    code = main(["convert-weights", *args, str(tmp_path / "r18.pth"), str(tmp_path / "o")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and message in error and len(error.splitlines()) == 1, error


def test_train_init_from_takes_the_backbone_and_initialises_the_rest(tmp_path, capsys, monkeypatch):
    source_model = build_model("deeplabv3plus_tiny", num_classes=19, attention=None, output_stride=16)
    rng = np.random.default_rng(0)
    shapes = jax.eval_shape(lambda x: source_model.init(jax.random.key(0), x, train=False),
                            np.zeros((1, 32, 32, 3), np.float32))
    source_vars = jax.tree.map(lambda s: rng.normal(size=s.shape).astype(np.float32) * 0.1 + 1, shapes)
    write_run(tmp_path / "source", "deeplabv3plus_tiny", source_model, source_vars)

    started = {}

    def train(config, model, batches, val, variables=None):  # the loop itself is tested elsewhere
        started.update(model=model, variables=variables)
        return types.SimpleNamespace(variables=variables)

    monkeypatch.setattr("jaxanom.train.segmenter.train", train)
    run = tmp_path / "run"
    assert main(["train", "--init-from", str(tmp_path / "source"), "--init-modules", "backbone", "--attention",
                 "cudam", "--steps", "1", "--batch-size", "4", "--out", str(run), "--no-progress"]) == 0
    experiment = load_experiment(run)
    assert (experiment.model, experiment.attention, experiment.init_modules) == ("deeplabv3plus_tiny", "cudam",
                                                                                 ("backbone",))
    assert (started["model"].attention, started["model"].output_stride) == ("cudam", 16)
    start = started["variables"]
    fresh = jax.jit(started["model"].init, static_argnames="train")(
        jax.random.key(experiment.train.seed), np.zeros((1, *experiment.crop, 3), np.float32), train=False)
    for collection in ("params", "batch_stats"):
        tree_equal(start[collection]["backbone"], source_vars[collection]["backbone"])
        tree_equal(start[collection]["decoder0"], jax.device_get(fresh[collection]["decoder0"]))
    tree_equal(start["params"]["cudam"], jax.device_get(fresh["params"]["cudam"]))
    # all modules of the source: the network (with CuDAM) has them all, so it starts from them
    everything = initial_variables(dataclasses.replace(experiment, init_modules=None))
    tree_equal(everything["params"]["aspp"], source_vars["params"]["aspp"])

    assert main(["train", "--init-from", str(tmp_path / "nowhere"), "--out", str(tmp_path / "r2")]) == 2
    assert "experiment.json" in capsys.readouterr().err


def test_take_modules_refuses_what_does_not_fit():
    fresh = {"params": {"backbone": {"w": np.zeros((3, 4))}, "classifier": {"kernel": np.zeros((4, 2))}},
             "batch_stats": {"backbone": {"mean": np.zeros(4)}}}
    source = {"params": {"backbone": {"w": np.ones((3, 4))}, "classifier": {"kernel": np.ones((4, 5))}},
              "batch_stats": {"backbone": {"mean": np.ones(4)}}}
    out = take_modules(fresh, source, ["backbone"])
    assert out["params"]["backbone"]["w"].sum() == 12 and out["batch_stats"]["backbone"]["mean"].sum() == 4
    assert out["params"]["classifier"]["kernel"].sum() == 0
    with pytest.raises(ValueError, match=r"params/classifier/kernel: source \(4, 5\), network \(4, 2\)"):
        take_modules(fresh, source)
    with pytest.raises(ValueError, match=r"cudam \(not in the network\)"):
        take_modules(fresh, source, ["cudam"])
    with pytest.raises(ValueError, match=r"params/backbone/v \(not in the network\)"):
        take_modules(fresh, {**source, "params": {**source["params"], "backbone": {"w": np.ones((3, 4)),
                                                                                   "v": np.ones(1)}}}, ["backbone"])


def test_take_modules_keeps_the_layers_it_is_told():
    fresh = {"params": {"decoder": {"up": {"w": np.zeros(3)}, "head": {"kernel": np.zeros((4, 2))}}},
             "batch_stats": {"decoder": {"up": {"mean": np.zeros(3)}}}}
    source = {"params": {"decoder": {"up": {"w": np.ones(3)}, "head": {"kernel": np.ones((4, 5))}}},
              "batch_stats": {"decoder": {"up": {"mean": np.ones(3)}}}}
    out = take_modules(fresh, source, keep=["decoder/head"])
    assert out["params"]["decoder"]["up"]["w"].sum() == 3 and out["batch_stats"]["decoder"]["up"]["mean"].sum() == 3
    head = out["params"]["decoder"]["head"]["kernel"]
    assert head.shape == (4, 2) and head.sum() == 0
    with pytest.raises(ValueError, match=r"decoder/hea \(kept, not a layer of the network\)"):
        take_modules(fresh, source, keep=["decoder/hea"])
    with pytest.raises(ValueError, match=r"params/decoder/head/kernel: source \(4, 5\), network \(4, 2\)"):
        take_modules(fresh, source, keep=["decoder/up"])
