"""Pixel AP + AUROC + FPR95 over a pooled dataset: jaxanom vs scikit-learn.

scikit-learn's way: ``average_precision_score``, ``roc_auc_score`` and ``roc_curve`` (for
FPR at 95% TPR, first point with TPR >= 0.95) on the non-void pixels, float64. jaxanom:
``anomaly_metrics`` (one packed-key sort on the device). The values are checked to agree to
1e-9 relative. "jnp.sort" is a plain-sort baseline: sorting the scores alone, nothing else.
peak_mb (not for the baseline): peak resident memory of a fresh process during one evaluation (host, Linux VmHWM
reset before it) above what it held before (inputs, libraries, a compiled program for jaxanom); on a GPU also the device's peak. 200M pixels only run when a GPU is present.
"""
from __future__ import annotations

import multiprocessing

import numpy as np

from benchmarks.timing import environment, markdown_table, median_ms, same_as_cpu


def make_data(pixels: int, seed: int = 0):
    """float32 scores (positives shifted up), uint8 labels: 5% anomaly, 10% void."""
    rng = np.random.default_rng(seed)
    labels = (rng.random(pixels, dtype=np.float32) < 0.05).astype(np.uint8)
    labels[rng.random(pixels, dtype=np.float32) < 0.10] = 255
    scores = rng.standard_normal(pixels, dtype=np.float32) + np.float32(1.5) * (labels == 1)
    return scores, labels


def sklearn_metrics(scores, labels):
    from sklearn import metrics

    kept = labels != 255
    y, s = labels[kept], scores[kept].astype(np.float64)
    fpr, tpr, _ = metrics.roc_curve(y, s, drop_intermediate=False)
    return {"ap": metrics.average_precision_score(y, s), "auroc": metrics.roc_auc_score(y, s),
            "fpr_at_tpr": float(fpr[np.searchsorted(tpr, 0.95)])}


def jaxanom_metrics(scores, labels):
    from jaxanom.metrics import anomaly_metrics

    return anomaly_metrics(scores, labels)


def plain_sort(scores, labels):
    import jax.numpy as jnp

    return jnp.sort(scores)


IMPLS = {"scikit-learn": sklearn_metrics, "jaxanom": jaxanom_metrics, "jnp.sort": plain_sort}


def _status_mb(field: str) -> float:
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith(field)) / 1024


def _peak_in_child(impl: str, pixels: int, queue) -> None:
    import jax

    scores, labels = make_data(pixels)
    if impl != "scikit-learn":
        scores, labels = jax.device_put(scores), jax.device_put(labels)
    before = _status_mb("VmRSS")
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")  # restart the peak (VmHWM) from the current resident size
    jax.block_until_ready(IMPLS[impl](scores, labels)) if impl != "scikit-learn" else IMPLS[impl](scores, labels)
    peak_host = _status_mb("VmHWM") - before
    stats = jax.devices()[0].memory_stats() or {}
    queue.put((peak_host, stats.get("peak_bytes_in_use", 0) / 2**20))


def peak_mb(impl: str, pixels: int) -> tuple[float, float]:
    """(host, device) peak memory in MiB of one evaluation in a fresh process."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_peak_in_child, args=(impl, pixels, queue))
    process.start()
    result = queue.get()
    process.join()
    return result


def run(quick: bool = False) -> list[dict]:
    import jax

    gpu = jax.default_backend() == "gpu"
    sizes = [2_000_000] if quick else [2_000_000, 20_000_000] + ([200_000_000] if gpu else [])
    rows = []
    for pixels in sizes:
        scores, labels = make_data(pixels)
        device_scores, device_labels = jax.device_put(scores), jax.device_put(labels)
        ours = jaxanom_metrics(device_scores, device_labels)
        times = {"jaxanom": median_ms(lambda: jaxanom_metrics(device_scores, device_labels),
                                      repeats=3 if pixels >= 20_000_000 else 5, warmup=1),
                 "jnp.sort": median_ms(lambda: plain_sort(device_scores, device_labels), repeats=3, warmup=1)}
        note = ("scikit-learn skipped (minutes); jaxanom on the CPU: "
                f"{same_as_cpu(lambda: jaxanom_metrics(scores, labels)['ap'], ours['ap']).lstrip('; ')} in AP")
        if pixels <= 20_000_000:
            reference = sklearn_metrics(scores, labels)
            worst = max(abs(ours[k] - reference[k]) / abs(reference[k]) for k in reference)
            if worst > 1e-9:
                raise AssertionError(f"jaxanom and scikit-learn differ by {worst:.3g} relative at {pixels} pixels")
            note = f"max relative difference to scikit-learn {worst:.1e}"
            times["scikit-learn"] = median_ms(lambda: sklearn_metrics(scores, labels), repeats=1, warmup=0)
        for impl, ms in times.items():
            host, device = peak_mb(impl, pixels) if impl != "jnp.sort" else (float("nan"),) * 2
            row = {"benchmark": "anomaly AP+AUROC+FPR95", "case": f"{pixels / 1e6:g}M px", "impl": impl,
                   "median_ms": ms, "ratio": times.get("scikit-learn", float("nan")) / ms,
                   "peak_mb": host, "note": note if impl == "jaxanom" else ""}
            if gpu:
                row["device_peak_mb"] = device
            rows.append(row)
    return rows


if __name__ == "__main__":
    import sys

    print(environment())
    print(markdown_table(run(quick="--quick" in sys.argv)))
