"""MSAAM's loss and objective (MSAAM Eq. 7; jaxanom.msaam.objective) against NumPy references."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.msaam.objective import MSAAM, msaam_loss
from loss_reference import VOID, random_batch, ref_cross_entropy, variants


@variants
@pytest.mark.parametrize("literal", [False, True])
def test_msaam_loss_matches_numpy(run, literal):
    logits, labels, _, _ = random_batch(16)
    z = np.random.default_rng(16).normal(size=(2, 3))
    weights = (np.exp(z) / np.exp(z).sum(1, keepdims=True)).astype(np.float32)
    got = run(lambda a, y, w: msaam_loss(a, y, w, lam=0.7, literal=literal), logits, labels, weights)
    variance = np.mean([np.mean((row - row.mean()) ** 2) for row in weights.astype(np.float64)])
    expected = ref_cross_entropy(logits, labels) + (0.7 if literal else -0.7) * variance
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def ref_branch_variance(z):
    weights = np.exp(z) / np.exp(z).sum(1, keepdims=True)
    return np.mean(np.var(weights, axis=1))


def test_msaam_default_gradient_spreads_the_branch_weights():
    logits, labels, _, _ = random_batch(17)
    z = jnp.asarray(np.random.default_rng(17).normal(size=(2, 3)) * 0.1, jnp.float32)

    def variance_after_step(literal):
        loss = lambda z: msaam_loss(logits, labels, jax.nn.softmax(z, -1), lam=1.0, literal=literal)
        z_new = np.asarray(z - 1.0 * jax.jit(jax.grad(loss))(z), np.float64)
        return ref_branch_variance(z_new)

    start = ref_branch_variance(np.asarray(z, np.float64))
    assert variance_after_step(False) > start > variance_after_step(True)

def test_bad_branch_weights_raise_value_error_naming_them():
    logits, labels, _, _ = random_batch(18)
    with pytest.raises(ValueError, match="branch_weights"):
        msaam_loss(logits, labels, np.ones((5, 3)), 0.1)


@pytest.mark.parametrize("literal", [False, True])
def test_msaam_objective_matches_numpy(literal):
    logits, labels, _, _ = random_batch(22)
    z = np.random.default_rng(22).normal(size=(2, 3))
    branch = (np.exp(z) / np.exp(z).sum(1, keepdims=True)).astype(np.float32)
    weights = (0.5, 1.0, 3.0, 1.0)
    outputs, batch = {"logits": jnp.asarray(logits), "branch_weights": jnp.asarray(branch)}, {"label": labels}
    loss, aux, state = MSAAM(lam=0.3, literal=literal, class_weights=weights).loss(outputs, batch, None, None, VOID)
    variance = np.mean(np.var(branch.astype(np.float64), axis=1))
    np.testing.assert_allclose(loss, ref_cross_entropy(logits, labels, weights) + (0.3 if literal else -0.3) * variance,
                               rtol=1e-5)
    assert aux == {} and state is None
