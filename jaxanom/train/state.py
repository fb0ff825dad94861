"""The training state: one pytree holding everything a step reads and writes."""
from __future__ import annotations

from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import optax


@flax.struct.dataclass
class TrainState:
    """Parameters, BatchNorm statistics, optimizer state, step counter, PRNG key data and the
    objective's state (``objective.init_state(num_classes)``, any pytree the trainer does not
    look into; None for an objective that keeps none, which adds nothing to the pytree or the
    checkpoints).

    ``rng`` holds raw key data (uint32, from ``jax.random.key_data``) so that checkpoints store a
    plain array; the key for step t is ``fold_in(key(rng), t)``, so a resumed run draws the same
    numbers as an uninterrupted one.
    """

    params: Any
    batch_stats: Any
    opt_state: Any
    step: jax.Array
    rng: jax.Array
    objective_state: Any = None

    @classmethod
    def create(cls, variables: dict, tx: optax.GradientTransformation, key: jax.Array,
               objective_state: Any = None) -> "TrainState":
        """A step-0 state from ``model.init``'s variables, a typed PRNG key and the objective's
        initial state."""
        params = variables["params"]
        return cls(
            params=params,
            batch_stats=variables.get("batch_stats", {}),
            opt_state=tx.init(params),
            step=jnp.zeros((), jnp.int32),
            rng=jax.random.key_data(key),
            # distinct buffers: the state is donated to the train step
            objective_state=jax.tree.map(jnp.array, objective_state),
        )

    @property
    def variables(self) -> dict:
        """``{"params", "batch_stats"}`` as ``model.apply`` wants them."""
        return {"params": self.params, "batch_stats": self.batch_stats}

    def step_key(self) -> jax.Array:
        """The typed PRNG key of the current step."""
        return jax.random.fold_in(jax.random.wrap_key_data(self.rng), self.step)
