"""jaxanom.losses (the cross-entropy, its class weights, the plain objective) against NumPy references."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom import losses
from loss_reference import VOID, random_batch, ref_cross_entropy, variants


@variants
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cross_entropy_matches_numpy(run, seed):
    logits, labels, _, _ = random_batch(seed)
    got = run(losses.cross_entropy, logits, labels)
    np.testing.assert_allclose(got, ref_cross_entropy(logits, labels), rtol=1e-5)


@variants
def test_cross_entropy_class_weights_match_numpy(run):
    logits, labels, _, _ = random_batch(3, c=5)
    weights = np.array([0.5, 2.0, 1.0, 0.0, 3.0], np.float32)
    got = run(lambda a, b: losses.cross_entropy(a, b, class_weights=weights), logits, labels)
    np.testing.assert_allclose(got, ref_cross_entropy(logits, labels, weights), rtol=1e-5)


@pytest.mark.parametrize("positive", [0.005, 0.3])
def test_balanced_class_weights_match_scikit_learn_and_average_the_classes(positive):
    from sklearn.utils.class_weight import compute_class_weight

    # rare positives (void clutter covers 0.49% of the MMF training pixels) and ignored pixels
    rng = np.random.default_rng(int(positive * 1000))
    labels = np.where(rng.random((4, 30, 40)) < positive, 1, 0)
    labels[rng.random(labels.shape) < 0.1] = VOID
    weights = losses.balanced_class_weights(labels, 2)
    valid = labels[labels != VOID]
    np.testing.assert_allclose(weights, compute_class_weight("balanced", classes=np.arange(2), y=valid), rtol=1e-12)
    # with these weights cross-entropy is the mean over classes of each class's mean loss
    logits = rng.normal(size=labels.shape + (2,)).astype(np.float32)
    log_p = logits - np.log(np.exp(logits).sum(-1, keepdims=True))
    nll = -np.take_along_axis(log_p, np.where(labels == VOID, 0, labels)[..., None], -1)[..., 0]
    expected = np.mean([nll[labels == c].mean() for c in (0, 1)])
    got = losses.cross_entropy(logits, labels, class_weights=weights.astype(np.float32))
    np.testing.assert_allclose(float(got), expected, rtol=1e-5)


def test_balanced_class_weights_edge_cases():
    np.testing.assert_allclose(losses.balanced_class_weights(np.array([0, 0, 2, VOID]), 3), [0.5, 0.0, 1.0])  # N = 3
    with pytest.raises(ValueError, match="at least one label"):
        losses.balanced_class_weights(np.full(4, VOID), 2)
    with pytest.raises(ValueError, match="expected values in"):
        losses.balanced_class_weights(np.array([0, 3]), 2)


def test_cross_entropy_ignores_void_logits_entirely():
    logits, labels, _, _ = random_batch(4)
    changed = logits.copy()
    changed[labels == VOID] = 1e6  # anything on void pixels must not matter
    assert losses.cross_entropy(changed, labels) == losses.cross_entropy(logits, labels)
    grad = jax.jit(jax.grad(losses.cross_entropy))(jnp.asarray(logits), labels)
    assert np.all(np.asarray(grad)[labels == VOID] == 0)


def test_cross_entropy_huge_logits_and_single_class():
    logits, labels, _, _ = random_batch(5, c=1, scale=1e4)
    assert float(losses.cross_entropy(logits, np.where(labels == VOID, VOID, 0))) == 0.0
    logits, labels, _, _ = random_batch(6, scale=1e4)
    got = losses.cross_entropy(logits, labels)
    np.testing.assert_allclose(got, ref_cross_entropy(logits, labels), rtol=1e-5)


def test_all_void_batch_gives_zero_not_nan():
    logits, labels, _, _ = random_batch(7)
    assert float(losses.cross_entropy(logits, np.full_like(labels, VOID))) == 0.0


@pytest.mark.parametrize("call, name", [
    (lambda l, y: losses.cross_entropy(l[..., 0], y), "logits"),
    (lambda l, y: losses.cross_entropy(l, y[:, :-1]), "labels"),
    (lambda l, y: losses.cross_entropy(l, y, class_weights=np.ones(2)), "class_weights"),
])
def test_bad_shapes_raise_value_error_naming_the_argument(call, name):
    logits, labels, _, _ = random_batch(18)
    with pytest.raises(ValueError, match=name):
        call(logits, labels)


def test_cross_entropy_objective_matches_numpy():
    from jaxanom.losses import CrossEntropy

    logits, labels, _, _ = random_batch(22)
    weights = (0.5, 1.0, 3.0, 1.0)
    loss, aux, state = CrossEntropy(class_weights=weights).loss({"logits": jnp.asarray(logits)}, {"label": labels},
                                                                None, None, VOID)
    np.testing.assert_allclose(loss, ref_cross_entropy(logits, labels, weights), rtol=1e-5)
    assert aux == {} and state is None
