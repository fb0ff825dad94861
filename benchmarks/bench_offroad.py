"""Off-road maths: EM for a full-covariance Gaussian mixture, and the dense CRF.

EM: ``jaxanom.mixture.em`` (float64, one jit-compiled while-loop) against scikit-learn's
``GaussianMixture(covariance_type="full")`` on the same points from the same initial parameters
(``weights_init``, ``means_init``, ``precisions_init``; ``init_params="random_from_data"`` so
that sklearn does not also run its k-means, whose result the given parameters replace), both for a fixed number of iterations
(``tol=0``) so they do the same work; the script checks that the two give the same parameters
before timing. Dense CRF: ``jaxanom.offroad.crf.dense_crf`` (permutohedral, 5 iterations)
against pydensecrf2 where it is importable (the optional ``crf`` extra), with the fraction of
equal labels as a note. Rows give ratio = this row's time / jaxanom's (above 1: jaxanom faster).

    PYTHONPATH=. python benchmarks/bench_offroad.py [--quick]
"""
from __future__ import annotations

import argparse
import warnings

import numpy as np

from benchmarks.timing import environment, markdown_table, median_ms


def mixture_data(n: int, dim: int, m: int, seed: int = 0):
    """``n`` points from ``m`` Gaussian blobs in ``dim`` dimensions, and a shared EM start."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(m, dim)) * 2
    z = centres[rng.integers(0, m, n)] + rng.normal(size=(n, dim))
    means = z[rng.choice(n, m, replace=False)]
    return z, np.full(m, 1.0 / m), means, np.stack([np.eye(dim) * 2.0] * m)


def run_em(quick: bool) -> list[dict]:
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.mixture import GaussianMixture

    from jaxanom.mixture import em

    n, dim, m, iters = (10_000 if quick else 100_000), 16, 8, 20
    z, weights, means, covariances = mixture_data(n, dim, m)

    def ours():
        return em(z, weights, means, covariances, tol=0.0, max_iter=iters).mixture.covariances

    def theirs():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            return GaussianMixture(m, covariance_type="full", weights_init=weights, means_init=means,
                                   precisions_init=np.linalg.inv(covariances), tol=0.0, max_iter=iters,
                                   init_params="random_from_data").fit(z)  # the cheapest init, overridden anyway

    fitted = theirs()
    result = em(z, weights, means, covariances, tol=0.0, max_iter=iters)
    diff = float(np.max(np.abs(np.asarray(result.mixture.covariances) - fitted.covariances_)))
    if diff > 1e-8 or int(result.n_iter) != fitted.n_iter_:
        raise AssertionError(f"jaxanom and sklearn EM disagree: max |cov diff| {diff}, iterations {int(result.n_iter)} vs {fitted.n_iter_}")
    case = f"{n}x{dim}, m={m}, {iters} iterations"
    repeats = 5 if quick else 3
    ours_ms = median_ms(ours, repeats=repeats, warmup=1)
    theirs_ms = median_ms(lambda: theirs().covariances_, repeats=repeats, warmup=0)  # nothing to compile
    return [dict(benchmark="gmm_em", case=case, impl="jaxanom", median_ms=ours_ms, ratio=1.0, note="mixture.em (float64)"),
            dict(benchmark="gmm_em", case=case, impl="sklearn", median_ms=theirs_ms, ratio=theirs_ms / ours_ms,
                 note=f"GaussianMixture(full); max |cov diff| {diff:.1e}")]


def crf_scene(height: int, width: int, num_labels: int, seed: int = 0):
    """Blocky labels, an image coloured by them plus noise, and noisy probabilities."""
    rng = np.random.default_rng(seed)
    cell = 16
    truth = rng.integers(0, num_labels, (-(-height // cell), -(-width // cell))).repeat(cell, 0).repeat(cell, 1)[:height, :width]
    image = np.clip(rng.random((num_labels, 3))[truth] + rng.normal(size=(height, width, 3)) * 0.05, 0, 1)
    logits = np.eye(num_labels)[truth] + rng.normal(size=(height, width, num_labels))
    probs = np.exp(logits) / np.exp(logits).sum(-1, keepdims=True)
    return probs.astype(np.float32), (image * 255).round().astype(np.uint8)


def run_crf(quick: bool) -> list[dict]:
    import jax

    from jaxanom.offroad.crf import dense_crf

    height, width, num_labels = (64, 128, 5) if quick else (128, 256, 5)
    probs, image = crf_scene(height, width, num_labels)
    image01 = image.astype(np.float32) / 255
    case = f"{height}x{width}x{num_labels}, 5 iterations"
    ours = lambda: dense_crf(probs, image01)  # noqa: E731
    labels = np.asarray(jax.block_until_ready(ours())).argmax(-1)
    ours_ms = median_ms(ours, repeats=5, warmup=1)
    rows = [dict(benchmark="dense_crf", case=case, impl="jaxanom", median_ms=ours_ms, ratio=1.0, note="permutohedral")]
    try:
        import pydensecrf.densecrf as dcrf
    except ImportError:
        return rows

    def theirs():
        model = dcrf.DenseCRF2D(width, height, num_labels)
        model.setUnaryEnergy(np.ascontiguousarray(-np.log(np.clip(probs, 1e-8, None)).reshape(-1, num_labels).T))
        model.addPairwiseGaussian(sxy=3, compat=3)
        model.addPairwiseBilateral(sxy=80, srgb=13, rgbim=np.ascontiguousarray(image), compat=10)
        return np.asarray(model.inference(5))

    agree = float(np.mean(theirs().reshape(num_labels, height, width).argmax(0) == labels))
    theirs_ms = median_ms(theirs, repeats=5, warmup=1)
    rows.append(dict(benchmark="dense_crf", case=case, impl="pydensecrf2", median_ms=theirs_ms, ratio=theirs_ms / ours_ms,
                     note=f"{100 * agree:.1f}% equal labels"))
    return rows


def run(quick: bool = False) -> list[dict]:
    return run_em(quick) + run_crf(quick)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10^4 points and a 64x128 image")
    args = parser.parse_args()
    print(environment())
    print(markdown_table(run(quick=args.quick)))
