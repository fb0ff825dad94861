"""Off-road maths: EM for a full-covariance Gaussian mixture, and the dense CRF.

EM: ``jaxanom.mixture.em`` (float64, one jit-compiled while-loop) against scikit-learn's
``GaussianMixture(covariance_type="full")`` on the same points from the same initial parameters
(``weights_init``, ``means_init``, ``precisions_init``; ``init_params="random_from_data"`` so
that sklearn does not also run its k-means, whose result the given parameters replace), both for a fixed number of iterations
(``tol=0``) so they do the same work; the script checks that the two give the same parameters
before timing. Dense CRF: ``jaxanom.offroad.crf.dense_crf`` / ``dense_crf_batch`` (permutohedral,
5 iterations, 5 labels, batch 1 and 8) against pydensecrf2 where it is importable (the optional
``crf`` extra), timed in turns, with the fraction of equal labels as a note. Rows give ratio = this row's time / jaxanom's (above 1: jaxanom faster).

    PYTHONPATH=. python benchmarks/bench_offroad.py [--quick] [--only em|crf]
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


def _interleaved_ms(fns: dict, repeats: int) -> dict:
    """Median wall time (ms) of each of ``fns`` (already warm), timed in turns so load hits all alike."""
    import time

    import jax

    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append((time.perf_counter() - start) * 1e3)
    return {name: float(np.median(t)) for name, t in times.items()}


def run_crf(quick: bool) -> list[dict]:
    """``dense_crf`` (batch 1) / ``dense_crf_batch`` (batch 8) against pydensecrf2 looping the
    frames, timed in turns; jaxanom's first call (tracing and compiling) reported apart."""
    import time

    from jaxanom.offroad.crf import dense_crf, dense_crf_batch

    rows = []
    for height, width in ([(64, 128)] if quick else [(128, 256), (512, 1024)]):
        for batch in (1, 8):
            scenes = [crf_scene(height, width, 5, seed) for seed in range(batch)]
            probs, images = np.stack([p for p, _ in scenes]), np.stack([i for _, i in scenes])
            images01 = images.astype(np.float32) / 255
            if batch == 1:
                ours = lambda: dense_crf(probs[0], images01[0])[None]  # noqa: E731
            else:
                ours = lambda: dense_crf_batch(probs, images01)  # noqa: E731
            start = time.perf_counter()
            labels = np.asarray(ours()).argmax(-1)
            first_ms = (time.perf_counter() - start) * 1e3
            case = f"{batch} x {height}x{width}x5, 5 iterations"
            fns = {"jaxanom": ours}
            note = ""
            try:
                import pydensecrf.densecrf as dcrf

                def theirs():
                    return np.stack([_pydensecrf(dcrf, p, i) for p, i in zip(probs, images)])

                agree = float(np.mean(theirs().argmax(-1) == labels))
                fns["pydensecrf2"] = theirs
                note = f"{100 * agree:.1f}% equal labels, frames in a loop"
            except ImportError:
                pass
            ms = _interleaved_ms(fns, repeats=3 if height * width * batch > 10**6 else 7)
            rows.append(dict(benchmark="dense_crf", case=case, impl="jaxanom", median_ms=ms["jaxanom"], ratio=1.0,
                             note=f"permutohedral; first call {first_ms:.0f} ms (compiles)"))
            if "pydensecrf2" in ms:
                rows.append(dict(benchmark="dense_crf", case=case, impl="pydensecrf2", median_ms=ms["pydensecrf2"],
                                 ratio=ms["pydensecrf2"] / ms["jaxanom"], note=note))
    return rows


def _pydensecrf(dcrf, probs, image):
    """pydensecrf2's mean field on one frame with ``dense_crf``'s defaults; Q ``(H, W, L)``."""
    height, width, num_labels = probs.shape
    model = dcrf.DenseCRF2D(width, height, num_labels)
    model.setUnaryEnergy(np.ascontiguousarray(-np.log(np.clip(probs, 1e-8, None)).reshape(-1, num_labels).T))
    model.addPairwiseGaussian(sxy=3, compat=3)
    model.addPairwiseBilateral(sxy=80, srgb=13, rgbim=np.ascontiguousarray(image), compat=10)
    return np.asarray(model.inference(5)).reshape(num_labels, height, width).transpose(1, 2, 0)


def run(quick: bool = False) -> list[dict]:
    return run_em(quick) + run_crf(quick)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10^4 points and 64x128 CRF frames")
    parser.add_argument("--only", choices=["em", "crf"], help="run one of the two benchmarks")
    args = parser.parse_args()
    print(environment())
    runs = {"em": run_em, "crf": run_crf}
    print(markdown_table(runs[args.only](args.quick) if args.only else run(quick=args.quick)))
