"""config_codec: every config dataclass to JSON and back, strict reading, ``--set`` overrides, the
files written before the codec, and the one config-file format of ``train`` and the demos."""
import dataclasses
import enum
import json
import typing
from pathlib import Path
from typing import Literal

import pytest
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st

from jaxanom.app.configs import load_config
from jaxanom.app.demos.sml_cudam import DemoConfig
from jaxanom.app.experiment import Experiment, jsonable, load_experiment
from jaxanom.app.mmf_experiment import MMFDemoConfig
from jaxanom.app.mmf_pipeline import MMFConfig
from jaxanom.app.offroad_experiment import OffroadDemoConfig, Source
from jaxanom.app.predict import PredictSettings
from jaxanom.cli import main
from jaxanom.config_codec import ConfigError, decode, encode, override
from jaxanom.cudam.objective import CuDAM
from jaxanom.msaam.objective import MSAAM
from jaxanom.objectives import Objective, objective_names
from jaxanom.train.segmenter import TrainConfig
from jaxanom.train.optim import OptimConfig

WRITTEN_BEFORE = Path(__file__).parent / "fixtures" / "configs"  # by jaxanom 8925539 (make_files.py)
# one valid instance of every command's config class: the values the random configs start from
BASES = {"experiment": Experiment(), "cudam_demo": DemoConfig(), "mmf_demo": MMFDemoConfig.quick(),
         "offroad_demo": OffroadDemoConfig.quick(), "predict": PredictSettings(methods=("msp", "entropy"))}


def _options(kind):
    return typing.get_args(kind) if typing.get_origin(kind) in (typing.Union, type(int | None)) else (kind,)


def _values(kind, base):
    """A strategy of values of the declared type ``kind`` near ``base`` (strings stay: no other is known valid)."""
    options = _options(kind)
    strategies = [st.none()] if type(None) in options else []
    for option in (o for o in options if o is not type(None)):
        origin, args = typing.get_origin(option), typing.get_args(option)
        if option is bool:
            strategies.append(st.booleans())
        elif option is int:
            strategies.append(st.integers(0, 40))
        elif option is float:
            strategies.append(st.floats(1e-6, 1.0, allow_subnormal=False))
        elif origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            element_base = base[0] if isinstance(base, tuple) and base else None
            if args[0] is not str and (args[0] in (int, float, bool) or element_base is not None):
                strategies.append(st.lists(_values(args[0], element_base), max_size=4).map(tuple))
        elif origin is tuple:
            strategies.append(st.tuples(*(_values(arg, None) for arg in args)))
        elif isinstance(option, type) and issubclass(option, Objective):
            strategies.append(st.sampled_from(objective_names()).flatmap(
                lambda name: configs(Objective.class_named(name)(), 0.5)))
        elif dataclasses.is_dataclass(option) and isinstance(base, option):
            strategies.append(configs(base))
    return st.one_of(*strategies, *([] if base is None else [st.just(base)]))


def configs(base, change: float = 0.25):
    """Valid configs of ``type(base)``: each field kept or, with probability ``change``, drawn anew."""
    @st.composite
    def build(draw):
        hints = typing.get_type_hints(type(base))
        fields = {}
        for field in dataclasses.fields(base):
            if field.init and draw(st.floats(0, 1)) < change:
                fields[field.name] = draw(_values(hints[field.name], getattr(base, field.name)))
        try:
            return dataclasses.replace(base, **fields)
        except ValueError:  # the config's own checks refuse it: draw another
            reject()
    return build()


def _text(value) -> str:
    """A JSON value as a user types it after ``--set NAME=``: lists of scalars comma-separated."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list) and not any(isinstance(item, (list, dict)) for item in value):
        return ",".join(_text(item) for item in value)
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value if isinstance(value, str) else repr(value)


def _assignments(before, after, prefix=""):
    """The ``NAME=VALUE`` assignments that make the encoded config ``before`` into ``after``: one per
    differing leaf, a whole object where a registered config changes its class."""
    if isinstance(after, dict) and isinstance(before, dict) and before.get("name") == after.get("name"):
        return [item for key in after for item in _assignments(before.get(key), after[key], f"{prefix}{key}.")]
    return [] if before == after else [f"{prefix[:-1]}={_text(after)}"]


def _with(config, path, value):
    """``config`` with the field at the dotted ``path`` replaced by ``value``."""
    name, _, rest = path.partition(".")
    return dataclasses.replace(config, **{name: _with(getattr(config, name), rest, value) if rest else value})


@pytest.mark.parametrize("name", sorted(BASES))
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow])
@given(data=st.data())
def test_every_command_config_round_trips_through_json_and_through_set(name, data):
    base = BASES[name]
    config = data.draw(configs(base))
    text = json.dumps(encode(config))
    assert decode(type(config), json.loads(text)) == config
    assert json.dumps(encode(decode(type(config), json.loads(text)))) == text
    # --set of every field that differs from the base turns the base into the drawn config
    assignments = _assignments(encode(base), encode(config))
    assert override(base, assignments) == config, assignments


@settings(max_examples=20, deadline=None)
@given(objective=st.sampled_from(objective_names()).flatmap(lambda name: configs(Objective.class_named(name)(), 0.5)))
def test_an_objective_is_read_back_as_its_registered_class(objective):
    values = json.loads(json.dumps(encode(objective)))
    assert values["name"] == objective.name
    read = decode(Objective, values)
    assert type(read) is type(objective) and read == objective
    assert decode(TrainConfig, {"run_dir": "", "objective": values}).objective == objective


class Colour(enum.Enum):
    RED = "red"
    BLUE = "blue"


@dataclasses.dataclass(frozen=True)
class Inner:
    size: int = 1
    scale: float = 0.5


@dataclasses.dataclass(frozen=True)
class Awkward:
    """What no shipped config has yet: required fields, unions, literals, enums, tuples of configs."""

    required: str
    inner: Inner | None = None
    inners: tuple[Inner, ...] = (Inner(),)
    pair: tuple[int, str] = (0, "a")
    either: int | str = 0
    mode: Literal["fast", "exact"] = "fast"
    colour: Colour = Colour.RED
    flags: tuple[bool, ...] = ()
    note: str | None = None
    fixed: str = dataclasses.field(default="awkward", init=False)


def _inner():
    return st.builds(Inner, st.integers(-5, 5), st.floats(allow_nan=False, allow_infinity=False))


@settings(max_examples=30, deadline=None)
@given(st.builds(Awkward, st.text(max_size=4), st.none() | _inner(), st.lists(_inner(), max_size=3).map(tuple),
                 st.tuples(st.integers(), st.text(max_size=3)), st.integers() | st.text(max_size=3),
                 st.sampled_from(["fast", "exact"]), st.sampled_from(Colour), st.lists(st.booleans(), max_size=3).map(tuple),
                 st.none() | st.text(max_size=3)))
def test_awkward_fields_round_trip(config):
    assert decode(Awkward, json.loads(json.dumps(encode(config)))) == config


@pytest.mark.parametrize("cls, values, message", [
    (Experiment, {"train": {"optim": {"lr": "fast"}}}, "train.optim.lr: expected a number, got 'fast'"),
    (Experiment, {"train": {"optim": {"lrate": 0.1}}}, "train.optim.lrate: unknown field of OptimConfig; expected one of"),
    (Experiment, {"batch_size": True}, "batch_size: expected an integer, got True"),
    (Experiment, {"batch_size": 4.0}, "batch_size: expected an integer, got 4.0"),
    (Experiment, {"crop": [64]}, r"crop: expected a list of 2 values \(an integer, an integer\), got 1: \[64\]"),
    (Experiment, {"crop": "64x96"}, "crop: expected a list of 2 values"),
    (Experiment, {"init_modules": [1]}, "init_modules.0: expected a string, got 1"),
    (Experiment, {"train": {"objective": {"name": "pebal"}}}, r"train.objective.name: expected one of \('cross_entropy'"),
    (Experiment, {"train": {"objective": {"tau": 3.0}}}, "train.objective.tau: unknown field of CrossEntropy"),
    (Experiment, {"train": {"objective": {"name": "msaam", "tau": 3.0}}}, "train.objective.tau: unknown field of MSAAM"),
    (Experiment, {"train": {"objective": {"class_weights": None, "name": 3}}}, "train.objective.name: expected a registered"),
    (Experiment, {"train": {"steps": 0}}, "train: steps must be >= 1, got 0"),
    (Experiment, [], r"expected an object of Experiment fields, got \[\]"),
    (TrainConfig, {"steps": 3}, "run_dir: missing: a TrainConfig has no default for it"),
    (PredictSettings, {}, "methods: missing"),
    (OffroadDemoConfig, {"train": [{"frames": "x"}]}, "train.0.frames: expected an integer, got 'x'"),
    (OffroadDemoConfig, {"pipeline": {"encoder": {"widths": [1, 2]}}}, "pipeline.encoder.widths: expected a list of 5"),
    (Awkward, {"required": "r", "fixed": "other"}, "fixed: expected 'awkward' in a Awkward, got 'other'"),
    (Awkward, {"required": "r", "mode": "slow"}, r"mode: expected one of \('fast', 'exact'\), got 'slow'"),
    (Awkward, {"required": "r", "colour": "green"}, r"colour: expected one of \('red', 'blue'\), got 'green'"),
    (Awkward, {"required": "r", "either": 1.5}, "either: expected an integer or a string, got 1.5"),
    (Awkward, {"required": "r", "inner": {"size": None}}, "inner.size: expected an integer, got None"),
])
def test_a_value_that_does_not_fit_is_named_by_its_dotted_path(cls, values, message):
    with pytest.raises(ConfigError, match=message):
        decode(cls, values)


def test_fields_left_out_keep_the_enclosing_configs_defaults():
    demo = decode(DemoConfig, {"experiment": {"train": {"steps": 7}}, "pictures": 1})
    assert demo == dataclasses.replace(DemoConfig(), pictures=1, experiment=dataclasses.replace(
        DemoConfig().experiment, train=dataclasses.replace(DemoConfig().experiment.train, steps=7)))
    assert decode(DemoConfig, {"experiment": {"train": {"objective": {"beta": 0.2}}}}).experiment.train.objective == \
        dataclasses.replace(DemoConfig().experiment.train.objective, beta=0.2)  # the demo's CuDAM, its tau kept
    assert decode(Experiment, {"train": {"objective": {"name": "cudam"}}}).train.objective == CuDAM()
    offroad = decode(OffroadDemoConfig, {"pipeline": {"budget": 3}})
    assert offroad.pipeline == dataclasses.replace(OffroadDemoConfig().pipeline, budget=3)
    assert offroad.train == OffroadDemoConfig().train


@pytest.mark.parametrize("assignments, expected", [
    (["train.optim.lr=1e-3"], {"train.optim.lr": 1e-3}),
    (["crop=64,96", "scale_range=[0.5, 1]"], {"crop": (64, 96), "scale_range": (0.5, 1.0)}),
    (["init_modules=backbone, aspp"], {"init_modules": ("backbone", "aspp")}),
    (["init_modules=", "data_root=none"], {"init_modules": (), "data_root": None}),
    (["train.progress=false", "train.distributed=TRUE"], {"train.progress": False, "train.distributed": True}),
    (["attention=cudam", "train.objective=cudam", "train.objective.tau=3", "train.objective.class_weights=1,2"],
     {"attention": "cudam", "train.objective": CuDAM(tau=3.0, class_weights=(1.0, 2.0))}),
    (["train.objective={\"name\": \"msaam\", \"lam\": 0.3}"], {"train.objective": MSAAM(lam=0.3)}),
    (["train.optim={\"lr\": 0.5}"], {"train.optim": OptimConfig(lr=0.5)}),
    (["train.optim.clip_norm=2", "train.optim.clip_norm=none"], {}),
])
def test_set_reads_each_value_as_its_fields_type(assignments, expected):
    want = Experiment()
    for path, value in expected.items():
        want = _with(want, path, value)
    # the JSON text tells 1 from 1.0: each value has its field's type, and nothing else moved
    assert json.dumps(encode(override(Experiment(), assignments))) == json.dumps(encode(want))


def test_set_of_a_json_object_keeps_the_fields_it_does_not_name():
    optim = DemoConfig().experiment.train.optim  # AdamW, not OptimConfig()'s SGD
    config = override(DemoConfig(), ["experiment.train.optim.momentum=0.5", 'experiment.train.optim={"lr": 0.5}'])
    assert config.experiment.train.optim == dataclasses.replace(optim, momentum=0.5, lr=0.5)
    # OptimConfig's "name" is a plain field (no registered family): merged like the others
    config = override(DemoConfig(), ['experiment.train={"steps": 9, "optim": {"name": "sgd", "lr": 0.5}}'])
    assert config.experiment.train == dataclasses.replace(DemoConfig().experiment.train, steps=9, optim=dataclasses.replace(
        optim, name="sgd", lr=0.5))
    # an objective of another registered class starts from that class's defaults
    config = override(DemoConfig(), ['experiment.train.objective={"name": "msaam", "lam": 0.5}'])
    assert config.experiment.train.objective == MSAAM(lam=0.5)


def test_set_reads_the_elements_of_a_tuple_by_their_declared_types():
    assert override(Awkward("r"), ["pair=3,b", "flags=yes,off", "either=7"]) == Awkward("r", pair=(3, "b"), flags=(True, False),
                                                                                       either=7)
    assert override(Awkward("r"), ["either=seven", "mode=exact", "colour=blue"]) == Awkward(
        "r", either="seven", mode="exact", colour=Colour.BLUE)
    with pytest.raises(ConfigError, match="pair: expected a list of 2 values \\(an integer, a string\\), got 'b,3'"):
        override(Awkward("r"), ["pair=b,3"])


def test_set_indexes_tuples_of_configs():
    config = override(OffroadDemoConfig.quick(), ["train.0.frames=3", "test.domain=E"])
    assert config.train[0] == Source("A", 0, 3, 0, 4) and config.test.domain == "E"


@pytest.mark.parametrize("assignment, message", [
    ("train.optim.lr", r"expected NAME=VALUE with a dotted field name \(e.g. train.optim.lr=1e-3\), got 'train.optim.lr'"),
    ("=3", "expected NAME=VALUE"),
    ("train.optim.lr=fast", "train.optim.lr: expected a number, got 'fast'"),
    ("train.steps=1.5", "train.steps: expected an integer, got '1.5'"),
    ("train.progress=maybe", "train.progress: expected true or false, got 'maybe'"),
    ("crop=1,2,3", r"crop: expected a list of 2 values \(an integer, an integer\), got '1,2,3'"),
    ("crop=[1,", "crop: expected JSON, got"),
    ("train.optm.lr=1", "train.optm: unknown field of TrainConfig; expected one of"),
    ("train.steps.every=1", "train.steps.every: train.steps is an integer, which has no member 'every'"),
    ("train.objective.tau=3", "train.objective.tau: unknown field of CrossEntropy"),
    ("train.objective=pebal", "train.objective.name: expected one of"),
    ("train.objective.nme=cudam", r"train.objective.nme: unknown field of CrossEntropy; expected one of "
                                  r"\['class_weights', 'name'\]"),
    ("train.objective.name=cudam", r"train.objective.name: is fixed by the class \(CrossEntropy's is "
                                   r"'cross_entropy'\); give train.objective whole to pick another, e.g. "
                                   r"train.objective=NAME"),
    ("init_modules.0=backbone", "init_modules: is none; give it whole first"),
    ("crop.2=5", "crop.2: expected an index below 2 of crop"),
    ("train.optim=0.5", "train.optim: expected an object of OptimConfig fields, got '0.5'"),
    ("train.optim.lr=-1", r"train.optim: lr must be a finite number in \(0.0, inf\], got -1.0"),
    ("train.run_dir=x", None),
])
def test_a_bad_set_is_refused_naming_the_dotted_path(assignment, message):
    if message is None:  # a plain string is taken as it is
        assert override(Experiment(), [assignment]).train.run_dir == "x"
        return
    with pytest.raises(ConfigError, match=message):
        override(Experiment(), [assignment])


@pytest.mark.parametrize("file, expected", [
    ("experiment_default.json", Experiment()),
    ("experiment_cudam_demo.json", DemoConfig().experiment),
    ("experiment_msaam.json", Experiment(
        attention="msaam", crop=(64, 96), init_from="/runs/espnet", init_modules=("backbone",),
        train=TrainConfig(run_dir="", steps=7, objective=MSAAM(lam=0.2, class_weights=(1.0, 0.5) * 9 + (2.0,)),
                          optim=OptimConfig(clip_norm=1.5, poly_power=0.0)))),
])
def test_experiment_json_written_before_the_codec_is_read_and_written_alike(tmp_path, file, expected):
    (tmp_path / "experiment.json").write_text((WRITTEN_BEFORE / file).read_text())
    assert load_experiment(tmp_path) == expected
    assert jsonable(expected) == json.loads((WRITTEN_BEFORE / file).read_text())


@pytest.mark.parametrize("text, message", [("{}", "train.run_dir: missing, in a file that jaxanom writes whole"),
                                           ('{"train": {"run_dir": ""}}', "train.optim: missing"),
                                           ('{"train": []}', "train.run_dir: missing")])
def test_a_run_folder_needs_an_experiment_json_written_whole(tmp_path, text, message):
    (tmp_path / "experiment.json").write_text(text)
    with pytest.raises(ConfigError, match=f"experiment.json: {message}"):
        load_experiment(tmp_path)


@pytest.mark.parametrize("file, cls, expected", [("mmf_results.json", MMFDemoConfig, MMFDemoConfig.quick()),
                                                 ("offroad_results.json", OffroadDemoConfig, OffroadDemoConfig.quick())])
def test_demo_results_written_before_the_codec_are_config_files(file, cls, expected):
    assert load_config(WRITTEN_BEFORE / file, cls) == expected
    assert encode(expected) == json.loads((WRITTEN_BEFORE / file).read_text())["config"]


def test_mmf_part_folders_keep_the_names_they_had_before_the_codec():
    keys = {part: MMFConfig.quick().part_key(part) for part in ("segmenter", "rgbd", "spade", "dissimilarity")}
    # computed by jaxanom 8925539; the dissimilarity key since, on purpose, by its revision text's rewording
    # (docs/decisions/mmf-second-look.md): 5193f7143f29 before it
    assert keys == {"segmenter": "ad1cdd744282", "rgbd": "65c1e8fa9db5", "spade": "dc704542c607",
                    "dissimilarity": "19760743a581"}


def test_a_python_config_and_its_json_are_the_same_config(tmp_path):
    python = tmp_path / "demo.py"
    python.write_text("from jaxanom.app.demos.sml_cudam import DemoConfig\nconfig = DemoConfig.quick()\n")
    (tmp_path / "demo.json").write_text(json.dumps(encode(DemoConfig.quick())))
    assert load_config(python, DemoConfig) == load_config(tmp_path / "demo.json", DemoConfig) == DemoConfig.quick()
    with pytest.raises(ConfigError, match=r"demo.py: expected it to define `experiment = Experiment\(...\)`, found"):
        load_config(python, Experiment, "experiment")
    (tmp_path / "bad.json").write_text('{"experiment": {"heigth": 3}}')
    with pytest.raises(ConfigError, match="bad.json: experiment.heigth: unknown field of Experiment"):
        load_config(tmp_path / "bad.json", DemoConfig)


@pytest.fixture
def started(monkeypatch):
    """What ``train`` and ``demo`` would start, instead of starting it."""
    import jaxanom.app.demos.sml_cudam
    import jaxanom.app.experiment

    calls = []
    monkeypatch.setattr(jaxanom.app.experiment, "run_training", lambda experiment, out, **_: calls.append(experiment))
    monkeypatch.setattr(jaxanom.app.demos.sml_cudam, "run_demo", lambda out, config, **_: calls.append(config))
    return calls


def test_train_and_demo_take_the_same_files_and_set(tmp_path, started, capsys):
    run_file = WRITTEN_BEFORE / "experiment_cudam_demo.json"  # a run's experiment.json as a config
    assert main(["train", "--config", str(run_file), "--out", str(tmp_path / "r"), "--steps", "40",
                 "--set", "train.optim.lr=0.5", "--set", "train.objective.beta=0.25", "--no-progress"]) == 0
    cudam = DemoConfig().experiment
    assert started.pop() == dataclasses.replace(cudam, train=dataclasses.replace(
        cudam.train, steps=40, optim=dataclasses.replace(cudam.train.optim, lr=0.5),
        objective=dataclasses.replace(cudam.train.objective, beta=0.25)))
    (tmp_path / "demo.json").write_text(json.dumps({"config": encode(DemoConfig.quick())}))  # as results.json
    assert main(["demo", "--config", str(tmp_path / "demo.json"), "--set", "experiment.train.seed=3",
                 "--out", str(tmp_path / "d"), "--no-progress"]) == 0
    quick = DemoConfig.quick()
    assert started.pop() == dataclasses.replace(quick, experiment=dataclasses.replace(
        quick.experiment, train=dataclasses.replace(quick.experiment.train, seed=3)))


def test_the_command_functions_name_config_and_overrides(tmp_path, started):
    """A Python caller of ``jaxanom.app.commands`` gets an InputError naming its own argument."""
    from jaxanom.app.commands.demo import demo
    from jaxanom.app.commands.train import train
    from jaxanom.errors import InputError

    with pytest.raises(InputError) as caught:
        train(out=str(tmp_path / "r"), overrides=["train.optim.lr=fast"], progress=False)
    assert (caught.value.argument, str(caught.value)) == \
        ("overrides", "overrides train.optim.lr: expected a number, got 'fast'")
    (tmp_path / "bad.json").write_text('{"experiment": {"heigth": 3}}')
    with pytest.raises(InputError) as caught:
        demo(config=str(tmp_path / "bad.json"), out=str(tmp_path / "d"), progress=False)
    assert caught.value.argument == "config"
    assert str(caught.value).startswith(f"config {tmp_path / 'bad.json'}: experiment.heigth: unknown field of Experiment")
    assert not started


@pytest.mark.parametrize("argv, message", [
    (["train", "--set", "train.optim.lr=fast"], "--set train.optim.lr: expected a number, got 'fast'"),
    (["train", "--set", "train.objective.tau=1"], "--set train.objective.tau: unknown field of CrossEntropy"),
    (["demo", "--quick", "--set", "experiment.train.steps=0"], "--set experiment.train: steps must be >= 1, got 0"),
    (["demo", "mmf", "--quick", "--set", "pipeline.dissim_lr=-1"], "--set pipeline: dissim_lr must be"),
    (["demo", "offroad", "--quick", "--set", "pipeline.encoder.widths=1,2"], "--set pipeline.encoder.widths: expected"),
    (["demo", "offroad", "--quick", "--config", "x.json"], "--quick, --config: give one of them"),
    (["predict", "a.png", "--run", "r", "--set", "size=12"], "--set size: expected a list of 2 values"),
])
def test_every_command_refuses_a_bad_set_before_any_work(tmp_path, started, capsys, argv, message):
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out), "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert not started and not out.exists()


def test_mmf_demo_config_round_trips_and_rejects_unknown_fields():
    config = MMFDemoConfig.quick()
    assert decode(MMFDemoConfig, json.loads(json.dumps(encode(config)))) == config
    assert decode(MMFDemoConfig, {"anomaly_frames": 5}) == MMFDemoConfig(anomaly_frames=5)
    with pytest.raises(ValueError, match="pipeline.dissim_stepz: unknown field of MMFConfig"):
        decode(MMFDemoConfig, {"pipeline": {"dissim_stepz": 3}})
    with pytest.raises(ValueError, match="expected an object of MMFDemoConfig fields, got"):
        decode(MMFDemoConfig, [1, 2])


@pytest.mark.parametrize("assignment", ["train.optim.clip_norm=nan", "train.optim.clip_norm=inf",
                                        "train.optim.lr=-Infinity", "train.optim.momentum=NaN",
                                        "scale_range=0.5,inf", 'train.optim={"weight_decay": NaN}'])
def test_set_gives_no_field_nan_or_infinity(assignment):
    with pytest.raises(ConfigError, match=r"expected a finite number, got (nan|inf|-inf)"):
        override(Experiment(), [assignment])


def test_config_files_give_no_field_nan_or_infinity(tmp_path):
    config = tmp_path / "experiment.json"
    config.write_text('{"train": {"optim": {"clip_norm": Infinity}}}')  # Python's json reads Infinity
    with pytest.raises(ConfigError, match=r"experiment.json: train.optim.clip_norm: expected a finite number, got inf"):
        load_config(config, Experiment)
    script = tmp_path / "exp.py"  # a Python config that slips a NaN past the dataclass's own checks
    script.write_text("from jaxanom.app.experiment import Experiment\nexperiment = Experiment()\n"
                      "object.__setattr__(experiment, 'scale_range', (0.5, float('nan')))\n")
    with pytest.raises(ConfigError, match=r"exp.py: scale_range.1: expected a finite number, got nan"):
        load_config(script, Experiment, "experiment")


def test_a_nan_clip_norm_is_refused_by_the_optimizer_config_and_experiment_json_holds_no_nan(tmp_path):
    from jaxanom.io import write_json_atomic

    with pytest.raises(ValueError, match="clip_norm must be a finite number"):
        OptimConfig(clip_norm=float("nan"))
    with pytest.raises(ValueError, match="Out of range float values are not JSON compliant"):
        write_json_atomic(tmp_path / "experiment.json", {"clip_norm": float("nan")}, allow_nan=False)
    assert list(tmp_path.iterdir()) == []


def test_train_refuses_a_nan_clip_norm_in_one_line_before_any_work(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--out", str(out), "--steps", "1", "--set", "train.optim.clip_norm=nan",
                 "--no-progress"]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "--set" in error and "train.optim.clip_norm: expected a finite number, got nan" \
        in error, error
    assert not out.exists()
