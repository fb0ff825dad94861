"""benchmarks/xla_cpu_profile: instructions sorted by pass and kind; a traced table that adds up."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.xla_cpu_profile import classify, profile_table

pytestmark = pytest.mark.skipif(jax.default_backend() != "cpu", reason="XLA:CPU's runtime events")


def _step():
    w = jnp.asarray(np.random.default_rng(0).normal(size=(64, 32)), jnp.float32)
    x = jnp.ones((16, 64), jnp.float32)
    fn = jax.jit(lambda w, x: w - 0.1 * jax.grad(lambda w: jnp.sum(jnp.tanh(x @ w) ** 2))(w))
    return fn, (w, x)


def test_classify_finds_forward_and_backward_dots_and_the_update():
    fn, args = _step()
    kinds = classify(fn.lower(*args).compile().as_text())
    values = set(kinds.values())
    assert ("forward", "dot") in values and ("backward", "dot") in values
    assert any(phase == "update" for phase, _ in values)


def test_profile_table_rows_add_up():
    fn, args = _step()
    table = profile_table(lambda: jax.block_until_ready(fn(*args)),
                          fn.lower(*args).compile().as_text(), calls=2)
    rows = [line.split("|")[1:-1] for line in table.splitlines()[2:]]
    total = float(rows[-1][2])
    assert rows[-1][0].strip() == "all" and total > 0
    assert sum(float(r[2]) for r in rows[:-1]) == pytest.approx(total, rel=0.01 * len(rows))
    assert any(r[1].strip() == "dot" for r in rows[:-1])
