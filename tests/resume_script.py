"""A tiny CuDAM training run for the kill-and-resume test: ``python resume_script.py RUN_DIR DELAY_S``.

Trains TinySegNet on 4 simulated CPU devices from a resumable input for STEPS steps, saving every
SAVE_EVERY steps and logging every step, and writes the final parameters to RUN_DIR/final.npz. DELAY_S slows each
batch down so that the test can kill the process mid-run.
"""
import sys

import jax

jax.config.update("jax_num_cpu_devices", 4)
jax.config.update("jax_platforms", "cpu")

import numpy as np  # noqa: E402

from jaxanom.train.segmenter import TrainConfig, train  # noqa: E402
from jaxanom.train.optim import OptimConfig  # noqa: E402
from jaxanom.cudam.objective import CuDAM  # noqa: E402
from tiny_models import IndexedBatches, TinySegNet, init_variables  # noqa: E402

STEPS, SAVE_EVERY = 12, 3


def main(run_dir: str, delay_s: float) -> None:
    config = TrainConfig(run_dir=run_dir, steps=STEPS, save_every=SAVE_EVERY, log_every=1, keep=2, progress=False,
                         objective=CuDAM(), optim=OptimConfig(lr=0.05, warmup_steps=2))
    state = train(config, TinySegNet(head="cudam"), IndexedBatches(seed=0, delay_s=delay_s),
                  variables=init_variables("cudam"))
    flat = {jax.tree_util.keystr(path): np.asarray(leaf)
            for path, leaf in jax.tree_util.tree_leaves_with_path(jax.device_get(state.params))}
    np.savez(f"{run_dir}/final.npz", **flat)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
