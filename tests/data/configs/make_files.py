"""Wrote the files beside it with jaxanom at commit 8925539, before config_codec (run from an export of that
commit: python make_files.py OUT); tests/test_config_codec.py reads them back with today's code."""
import dataclasses, json, sys
from pathlib import Path
from jaxanom.io import write_json_atomic
from jaxanom.app.experiment import Experiment, jsonable
from jaxanom.app.demos.sml_cudam import DemoConfig
from jaxanom.app.demos.mmf import MMFDemoConfig
from jaxanom.app.demos.offroad import OffroadDemoConfig
from jaxanom.msaam_objective import MSAAM
from jaxanom.train.loop import TrainConfig
from jaxanom.train.optim import OptimConfig
out = Path(sys.argv[1])
msaam = Experiment(attention="msaam", crop=(64, 96), init_from="/runs/espnet", init_modules=("backbone",),
                   train=TrainConfig(run_dir="", steps=7, objective=MSAAM(lam=0.2, class_weights=(1.0, 0.5) * 9 + (2.0,)),
                                     optim=OptimConfig(clip_norm=1.5, poly_power=0.0)))
write_json_atomic(out / "experiment_default.json", jsonable(Experiment()))
write_json_atomic(out / "experiment_msaam.json", jsonable(msaam))
write_json_atomic(out / "experiment_cudam_demo.json", jsonable(DemoConfig().experiment))
write_json_atomic(out / "mmf_results.json", {"metrics": {}, "config": dataclasses.asdict(MMFDemoConfig.quick())})
write_json_atomic(out / "offroad_results.json", {"test_after": {}, "config": json.loads(json.dumps(dataclasses.asdict(OffroadDemoConfig.quick()), default=str))})
