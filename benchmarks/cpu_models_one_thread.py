"""DeepLabV3+ R101 on the CPU against PyTorch: one thread each, process CPU time, interleaved.

On a shared machine wall time says little (PyTorch's OpenMP workers spin on descheduled threads),
so each library runs on one thread (``torch.set_num_threads(1)``,
``--xla_cpu_multi_thread_eigen=false``) and the two alternate call by call in one process; a row
is the median ``getrusage`` CPU time of ``repeats`` calls. Sizes, weights and steps are
``bench_models.py``'s (forward 1x64x128, train step 2x64x64 with CuDAM, SGD + momentum, float32);
jaxanom's steps are jitted as the trainer's are (``conv_compiler_options``, ``state_donation``).
``--profile`` also prints XLA's per-op times of the train step, summed by kind
(``benchmarks/xla_cpu_profile.py``). docs/decisions/cpu-speed.md has the analysis. Not a
``bench_*`` module: ``python -m benchmarks`` runs those in one process, where XLA's thread
option set here (before JAX starts) could not apply; run this script on its own.

    PYTHONPATH=. python benchmarks/cpu_models_one_thread.py [--repeats N] [--profile]
"""
from __future__ import annotations

import os

os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()

import argparse  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.bench_models import NUM_CLASSES, _host_variables, _torch_deeplab, train_step_run  # noqa: E402
from benchmarks.timing import environment, markdown_table  # noqa: E402
from jaxanom.models import build_model  # noqa: E402
from jaxanom.xla_options import conv_compiler_options  # noqa: E402

FORWARD, TRAIN = (1, 64, 128), (2, 64, 64)


def _cpu_ms() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return (usage.ru_utime + usage.ru_stime) * 1e3


def jax_forward():
    model = build_model("deeplabv3plus_r101", NUM_CLASSES)
    variables = _host_variables(model, FORWARD)
    images = jnp.asarray(np.random.default_rng(1).normal(size=(*FORWARD, 3)).astype(np.float32))
    forward = jax.jit(lambda v, x: model.apply(v, x, train=False)["logits"],
                      compiler_options=conv_compiler_options())
    return lambda: jax.block_until_ready(forward(variables, images))


def jax_train_step():
    """``(run, jitted step, its arguments)``: one call of ``run`` is one SGD step of the CuDAM network."""
    return train_step_run("deeplabv3plus_r101", TRAIN)


def torch_forward():
    import torch

    net = _torch_deeplab(None).eval()
    x = torch.randn(FORWARD[0], 3, *FORWARD[1:])

    def run():
        with torch.no_grad():
            return net(x)

    return run


def torch_train_step():
    import torch

    net = _torch_deeplab("cudam").train()
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9)
    x = torch.randn(TRAIN[0], 3, *TRAIN[1:])
    y = torch.randint(0, NUM_CLASSES, TRAIN)

    def run():
        opt.zero_grad(set_to_none=True)
        loss = torch.nn.functional.cross_entropy(net(x), y)
        loss.backward()
        opt.step()
        return loss

    return run


def interleaved_cpu_ms(fns: dict, repeats: int, warmup: int = 2) -> dict[str, list[float]]:
    """CPU ms of each call of each function, the functions alternating call by call."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = _cpu_ms()
            fn()
            times[name].append(_cpu_ms() - start)
    return times


def run(repeats: int = 7) -> list[dict]:
    import torch

    torch.set_num_threads(1)
    rows = []
    for benchmark, case, ours, peer in (("forward", "R101 OS8 1x64x128 float32", jax_forward, torch_forward),
                                        ("train step", "R101 OS8 + CuDAM 2x64x64 float32",
                                         lambda: jax_train_step()[0], torch_train_step)):
        times = interleaved_cpu_ms({"jaxanom": ours(), "pytorch": peer()}, repeats)
        med = {name: statistics.median(t) for name, t in times.items()}
        for name, t in times.items():
            ratio = {"ratio": med["pytorch"] / med["jaxanom"]} if name == "jaxanom" else {}
            rows.append({"benchmark": benchmark, "case": case, "impl": name, "median_ms": med[name], **ratio,
                         "note": "CPU ms, one thread: " + " ".join(f"{v:.0f}" for v in t)})
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--profile", action="store_true")
    args = parser.parse_args()
    print(environment(), "| load:", os.getloadavg())
    print(markdown_table(run(args.repeats), ["benchmark", "case", "impl", "median_ms", "ratio", "note"]))
    if args.profile:
        from benchmarks.xla_cpu_profile import profile_table

        step, jitted, step_args = jax_train_step()
        print(profile_table(step, jitted.lower(*step_args[0], *step_args[1:]).compile().as_text()))
    print("load after:", os.getloadavg())
