"""jaxanom.cudam.losses (Eqs. 4, 7, 9) and the CuDAM objective (Eq. 8) against NumPy references
written from the paper's equations."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.cudam import losses
from loss_reference import VOID, random_batch, ref_correct, ref_cross_entropy, ref_log_softmax, variants


def ref_attention_loss(m, logits, labels, k, beta, literal):
    total = 0.0
    for i in range(len(labels)):
        correct = ref_correct(logits[i], labels[i])
        incorrect = (labels[i] != VOID) & ~correct
        if not correct.any():
            continue
        psi = m[i][correct].astype(np.float64).mean()
        pen = incorrect & (m[i] < beta * psi)
        term = m[i] if literal else beta * psi - m[i]
        total += np.sum(np.exp(k[i][pen].astype(np.float64)) * term[pen])
    return total / len(labels)



def test_all_void_batch_gives_zero_not_nan():
    logits, labels, attention, score = random_batch(7)
    void = np.full_like(labels, VOID)
    assert float(losses.attention_loss(attention, logits, void, score)) == 0.0
    assert float(losses.self_regulated_lambda(logits, void)) == 0.0


@variants
def test_reward_logits_matches_eq4_and_skips_void(run):
    logits, labels, attention, _ = random_batch(8)
    got = np.asarray(run(lambda a, m, y: losses.reward_logits(a, m, y, tau=5e4), logits, attention, labels))
    expected = logits.astype(np.float64).copy()
    for idx in np.ndindex(labels.shape):
        if labels[idx] != VOID:
            expected[idx][labels[idx]] += 5e4 * attention[idx]
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    np.testing.assert_array_equal(got[labels == VOID], logits[labels == VOID])


@pytest.mark.parametrize("prob", [0.0, 1.0, 0.5])
def test_study_draw_frequency(prob):
    logits, labels, attention, _ = random_batch(9)
    keys = jax.random.split(jax.random.key(0), 400)
    draw = jax.vmap(lambda k: losses.study_logits(k, logits, attention, labels, reward_prob=prob))
    rewarded_all, study = draw(keys)
    study = np.asarray(study)
    if prob in (0.0, 1.0):
        assert np.all(study == bool(prob))
    else:
        assert 0.4 < study.mean() < 0.6  # 400 draws: 4 standard deviations
    rewarded = np.asarray(losses.reward_logits(logits, attention, labels))
    rewarded_all = np.asarray(rewarded_all)
    for s, got in zip(study, rewarded_all):
        np.testing.assert_array_equal(got, rewarded if s else logits)
        np.testing.assert_array_equal(got[labels == VOID], logits[labels == VOID])


@variants
@pytest.mark.parametrize("literal", [False, True])
@pytest.mark.parametrize("seed", [10, 11])
def test_attention_loss_matches_numpy(run, literal, seed):
    logits, labels, attention, score = random_batch(seed, b=3, h=6, w=5)
    # make half of the pixels low-attention so that the beta * psi condition selects some
    attention = attention * np.where(np.random.default_rng(seed).random(attention.shape) < 0.5, 0.1, 1.0)
    got = run(lambda m, a, y, k: losses.attention_loss(m, a, y, k, beta=0.5, literal=literal),
              attention, logits, labels, score)
    expected = ref_attention_loss(attention, logits, labels, score, 0.5, literal)
    assert expected > 0
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_attention_loss_with_ties_and_image_without_correct_pixels():
    logits, labels, attention, score = random_batch(12, b=2, c=3)
    logits = np.round(logits / 3).astype(np.float32)  # many ties in argmax: the first maximum wins
    labels[0] = np.where(labels[0] == VOID, VOID, (np.argmax(logits[0], -1) + 1) % 3)  # image 0: nothing correct
    got = losses.attention_loss(attention, logits, labels, score)
    np.testing.assert_allclose(got, ref_attention_loss(attention, logits, labels, score, 0.5, False), rtol=1e-5)


def _attention_step(literal):
    """One gradient step on attention logits z (softmax per image); mean attention on incorrect and correct pixels."""
    logits, labels, _, score = random_batch(13, b=2, h=8, w=8, void=0.1)
    incorrect = (labels != VOID) & ~ref_correct(logits, labels)
    correct = ref_correct(logits, labels)
    z = np.where(incorrect, -1.0, 0.0).reshape(2, -1)  # incorrect pixels start with low attention

    def attention_of(z):
        return jax.nn.softmax(z, axis=-1).reshape(labels.shape)

    def loss(z):
        return losses.attention_loss(attention_of(z), logits, labels, score, literal=literal)

    z_new = z - 1e3 * np.asarray(jax.jit(jax.grad(loss))(jnp.asarray(z, jnp.float32)))
    before, after = np.asarray(attention_of(z)), np.asarray(attention_of(z_new))
    ratio_before = before[incorrect].mean() / before[correct].mean()
    ratio_after = after[incorrect].mean() / after[correct].mean()
    return ratio_before, ratio_after, before, after, incorrect, correct


def test_default_attention_loss_raises_attention_on_incorrect_pixels():
    ratio_before, ratio_after, before, after, incorrect, correct = _attention_step(literal=False)
    assert ratio_after > ratio_before
    assert after[incorrect].mean() > before[incorrect].mean()
    assert after[correct].mean() < before[correct].mean()


def test_literal_attention_loss_lowers_attention_on_incorrect_pixels():
    ratio_before, ratio_after, *_ = _attention_step(literal=True)
    assert ratio_after < ratio_before


@variants
@pytest.mark.parametrize("seed", [14, 15])
def test_self_regulated_lambda_matches_eq9(run, seed):
    logits, labels, _, _ = random_batch(seed)
    expected = ref_correct(logits, labels).sum() / (labels != VOID).sum()
    np.testing.assert_allclose(run(losses.self_regulated_lambda, logits, labels), expected, rtol=1e-6)


@pytest.mark.parametrize("call, name", [
    (lambda l, y, m, k: losses.reward_logits(l, m[:, :-1], y), "attention_up"),
    (lambda l, y, m, k: losses.attention_loss(m, l, y, k[:1]), "anomaly_score"),
])
def test_bad_shapes_raise_value_error_naming_the_argument(call, name):
    logits, labels, attention, score = random_batch(18)
    with pytest.raises(ValueError, match=name):
        call(logits, labels, attention, score)


# The objective composing these losses, against the same references.

def ref_msp_k(logits):
    z = np.exp(ref_log_softmax(logits))
    return 1.0 - z.max(-1)

@pytest.mark.parametrize("study, tau, literal, weights", [(True, None, False, None),
                                                         (False, 40.0, True, (1.0, 0.5, 2.0, 0.0))])
def test_cudam_objective_is_eq8_with_psi_and_lambda_on_the_network_logits(study, tau, literal, weights):
    from jaxanom.cudam.objective import CuDAM
    from jaxanom.cudam.score import paper_tau

    logits, labels, attention, _ = random_batch(20, b=3, h=6, w=5)
    attention = attention * np.where(np.random.default_rng(20).random(attention.shape) < 0.5, 0.1, 1.0)
    objective = CuDAM(tau=tau, reward_prob=float(study), beta=0.7, attention_literal=literal, class_weights=weights)
    loss, aux, state = jax.jit(lambda a, m, y: objective.loss({"logits": a, "attention": m}, {"label": y},
                                                              jax.random.key(0), None, VOID))(logits, attention, labels)
    # the map is at label size here, so up(.) is the identity
    rewarded = logits.astype(np.float64) + study * (paper_tau(30) if tau is None else tau) * (
        attention[..., None] * np.eye(4)[np.where(labels == VOID, 0, labels)] * (labels != VOID)[..., None])
    seg = ref_cross_entropy(rewarded, labels, weights)
    att = ref_attention_loss(attention, logits, labels, ref_msp_k(logits), 0.7, literal)
    lam = ref_correct(logits, labels).sum() / (labels != VOID).sum()
    assert att > 0 and bool(aux["study"]) == study and state is None
    np.testing.assert_allclose([aux["seg_loss"], aux["attention_loss"], aux["lambda"], loss],
                               [seg, att, lam, seg + lam * att], rtol=2e-5)


def test_cudam_objective_with_running_sml_k_updates_its_state_first():
    from jaxanom.cudam.objective import CuDAM
    from jaxanom.sml.running import running_sml_score, running_stats_update

    logits, labels, attention, _ = random_batch(21, b=2, h=6, w=5)
    objective = CuDAM(tau=3.0, reward_prob=0.0, beta=2.0, attention_k="running_sml", sml_decay=0.9)
    state = objective.init_state(4)
    state = running_stats_update(state, logits * 0.5, labels != VOID, 0.9)  # an earlier batch
    loss, aux, new_state = objective.loss({"logits": jnp.asarray(logits), "attention": jnp.asarray(attention)},
                                          {"label": labels}, jax.random.key(0), state, VOID)
    expected_state = running_stats_update(state, logits, labels != VOID, 0.9)
    for got, want in zip(new_state, expected_state):
        np.testing.assert_array_equal(got, want)
    k = np.asarray(running_sml_score(expected_state, logits))
    att = ref_attention_loss(attention, logits, labels, k, 2.0, False)
    lam = ref_correct(logits, labels).sum() / (labels != VOID).sum()
    assert att > 0
    np.testing.assert_allclose(loss, ref_cross_entropy(logits, labels) + lam * att, rtol=2e-5)
