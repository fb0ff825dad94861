"""MMF's post-processor: SLIC superpixels (Algorithm 1) and the superpixel score (Eq. 6).

- ``slic``: ``superpixels.slic_batch(rgb_to_lab(images))`` against scikit-image's ``slic`` on the
  same RGB frames (its own Lab conversion, the same K, compactness 10, 10 iterations, no
  connectivity enforcement), one call per image. The two algorithms differ in detail (grid
  offsets, distance scaling), so the check before timing is agreement by adjusted Rand index.
- ``eq6``: ``mmf.postprocess.superpixel_score_batch`` against the same equation in NumPy
  (bincount statistics, a K x K weight matrix, one image at a time); the maps must agree.

- ``eq6 memory``: Eq. 6 at 1080x1920 (quick: 540x960), each implementation in a fresh process
  (``bench_score_memory._peak_of``: peak resident MiB, its ``VmHWM``, runtime included) on SLIC
  labels of a frame at the scaled step (``superpixels.scaled_step``, K ~ 2048) and on the 16- and
  8-px grids (K = 8 040, 32 400): jaxanom blockwise (default blocks), the same with one K x K
  block (the dense formulation Eq. 6 had before; not at K = 32 400, where it needs ~16 GB) and the
  NumPy float64 peer with its K x K matrix (K ~ 2048 only). Times are the median
  of 3 calls after a warm-up inside the child; the maps must agree with NumPy's.

- ``synthesis``: the SPADE generator's forward pass (docs/papers/mmf.md#spade-generator: nf 8, n 3, SPADE hidden
  32, random weights) against the class-mean gather on the same batch of semantic maps (Table 4:
  the two synthesizers' cost; ratio = SPADE / class means, both jaxanom).

Frames: real Road Anomaly frames (the real-data folder, ``JAXANOM_REALDATA``) resized to the
evaluation size of docs/papers/mmf.md#superpixel-step, else a synthetic blocky image. Step S = 8 px. Rows give
ratio = this row's time / jaxanom's (above 1: jaxanom is faster).

    PYTHONPATH=. python benchmarks/bench_mmf.py [--quick]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from benchmarks.timing import environment, markdown_table, median_ms

STEP = 8


def frames(count: int, height: int, width: int) -> tuple[np.ndarray, str]:
    """(count, H, W, 3) uint8 RGB frames and where they come from."""
    import cv2

    root = Path(os.environ.get("JAXANOM_REALDATA", Path(__file__).resolve().parents[2] / "shared" / "realdata"))
    paths = sorted((root / "RoadAnomaly_sample" / "frames").glob("*.jpg"))
    if paths:
        images = [cv2.resize(cv2.cvtColor(cv2.imread(str(paths[i % len(paths)])), cv2.COLOR_BGR2RGB), (width, height),
                             interpolation=cv2.INTER_AREA) for i in range(count)]
        return np.stack(images), "Road Anomaly frames"
    rng = np.random.default_rng(0)
    blocks = rng.integers(0, 256, (count, -(-height // 24), -(-width // 24), 3), dtype=np.uint8)
    images = np.repeat(np.repeat(blocks, 24, 1), 24, 2)[:, :height, :width]
    return np.clip(images + rng.normal(0, 8, images.shape), 0, 255).astype(np.uint8), "synthetic blocks"


def numpy_superpixel_score(anomaly, road, labels, k):
    """Eq. 6 (docs/papers/mmf.md#superpixel-scores) for one image in NumPy float64."""
    height, width = labels.shape
    flat = labels.ravel()
    counts = np.bincount(flat, minlength=k).astype(np.float64)
    valid = counts > 0
    mean = lambda v: np.bincount(flat, v.ravel(), minlength=k) / np.maximum(counts, 1)  # noqa: E731
    ys, xs = np.mgrid[:height, :width]
    alpha, p, cy, cx = mean(anomaly), mean(road), mean(ys), mean(xs)
    r2 = (cy[:, None] - cy[None]) ** 2 + (cx[:, None] - cx[None]) ** 2
    i, j = np.triu_indices(k, 1)
    omega = np.median(np.sqrt(r2[i, j][valid[i] & valid[j]]))
    with np.errstate(invalid="ignore", divide="ignore"):
        weight = np.where(r2 == 0, 1.0, np.exp(-r2 / (2 * omega**2)))
    pair = valid[None, :] & ~np.eye(k, dtype=bool)
    score = alpha * np.sum(np.where(pair, p * counts / (height * width) * weight, 0.0), axis=1)
    low, high = score[valid].min(), score[valid].max()
    normalised = np.where(valid, (score - low) / (high - low), 0.0) if high > low else np.zeros(k)
    return normalised[labels]


def run(quick: bool = False) -> list[dict]:
    import jax
    from skimage.segmentation import slic as skimage_slic
    from sklearn.metrics import adjusted_rand_score

    from jaxanom.mmf.postprocess import superpixel_score_batch
    from jaxanom.superpixels import num_superpixels, rgb_to_lab, slic_batch

    height, width = (128, 256) if quick else (256, 512)
    k = num_superpixels((height, width), STEP)
    rows = []
    for batch in (1, 8):
        images, source = frames(batch, height, width)
        images_jax = jax.device_put(images)
        ours = lambda: slic_batch(rgb_to_lab(images_jax), STEP)  # noqa: E731
        labels = np.asarray(ours())
        theirs = lambda: [skimage_slic(image, n_segments=k, compactness=10.0, max_num_iter=10,  # noqa: E731
                                       enforce_connectivity=False, start_label=0) for image in images]
        ari = min(adjusted_rand_score(t.ravel(), o.ravel()) for t, o in zip(theirs(), labels))
        if ari < 0.5:
            raise AssertionError(f"jaxanom and scikit-image SLIC disagree: ARI {ari:.2f} at batch {batch}")
        case = f"{batch}x{height}x{width}, K={k}"
        repeats = 5 if quick else 3
        jax_ms = median_ms(ours, repeats=repeats, warmup=1)
        rows.append(dict(benchmark="slic", case=case, impl="jaxanom", median_ms=jax_ms, ms_per_frame=jax_ms / batch,
                         ratio=1.0, note=f"rgb_to_lab + slic_batch, {source}"))
        peer_ms = median_ms(theirs, repeats=repeats, warmup=1)
        rows.append(dict(benchmark="slic", case=case, impl="scikit-image slic", median_ms=peer_ms,
                         ms_per_frame=peer_ms / batch, ratio=peer_ms / jax_ms, note=f"min ARI vs jaxanom {ari:.2f}"))

        rng = np.random.default_rng(batch)
        anomaly, road = rng.random((2, batch, height, width)).astype(np.float32)
        anomaly_jax, road_jax, labels_jax = (jax.device_put(x) for x in (anomaly, road, labels))
        ours = lambda: superpixel_score_batch(anomaly_jax, road_jax, labels_jax, k)  # noqa: E731
        reference = np.asarray(ours())
        theirs = lambda: [numpy_superpixel_score(a, r, l, k) for a, r, l in zip(anomaly, road, labels)]  # noqa: E731
        diff = float(np.max(np.abs(np.stack(theirs()) - reference)))
        if diff > 1e-4:
            raise AssertionError(f"jaxanom and NumPy Eq. 6 disagree by {diff} at batch {batch}")
        jax_ms = median_ms(ours, repeats=repeats, warmup=1)
        rows.append(dict(benchmark="eq6", case=case, impl="jaxanom", median_ms=jax_ms, ms_per_frame=jax_ms / batch,
                         ratio=1.0, note=f"superpixel_score_batch (jit; {'lax.map' if jax.default_backend() == 'cpu' else 'vmap'})"))
        peer_ms = median_ms(theirs, repeats=repeats, warmup=1)
        rows.append(dict(benchmark="eq6", case=case, impl="numpy", median_ms=peer_ms, ms_per_frame=peer_ms / batch,
                         ratio=peer_ms / jax_ms, note=f"float64, max |diff| {diff:.1e}"))
        rows.extend(synthesis_rows(batch, height, width, repeats))
    return rows + eq6_memory_rows(quick)


_EQ6_CHILD = """
import sys, time
import numpy as np
data = np.load(sys.argv[1])
anomaly, road, labels, k = data["anomaly"], data["road"], data["labels"], int(data["k"])
if sys.argv[2] == "numpy":
    from benchmarks.bench_mmf import numpy_superpixel_score
    call = lambda: numpy_superpixel_score(anomaly, road, labels, k)
else:
    from jaxanom.mmf.postprocess import superpixel_score
    rows = None if sys.argv[2] == "jaxanom blockwise" else k
    call = lambda: np.asarray(superpixel_score(anomaly, road, labels, k, block_rows=rows))
result = call()
times = []
for _ in range(3):
    start = time.perf_counter()
    call()
    times.append(time.perf_counter() - start)
np.save(sys.argv[3], result.astype(np.float32))
open(sys.argv[3] + ".ms", "w").write(str(1e3 * float(np.median(times))))
"""


def eq6_memory_rows(quick: bool) -> list[dict]:
    """Eq. 6's peak memory and time at a real resolution, one fresh process per implementation."""
    import tempfile

    from benchmarks.bench_score_memory import _peak_of
    from jaxanom.superpixels import _grid_cells, num_superpixels, rgb_to_lab, scaled_step, slic

    height, width = (540, 960) if quick else (1080, 1920)
    image, source = frames(1, height, width)
    rng = np.random.default_rng(0)
    anomaly, road = rng.random((2, height, width)).astype(np.float32)
    step = scaled_step((height, width))
    cases = [(f"SLIC S={step}", np.asarray(slic(rgb_to_lab(image[0]), step)), num_superpixels((height, width), step),
              ("jaxanom blockwise", "jaxanom one K x K block", "numpy")),
             ("16-px grid", np.asarray(_grid_cells(height, width, 2 * STEP)),
              num_superpixels((height, width), 2 * STEP), ("jaxanom blockwise", "jaxanom one K x K block")),
             ("8-px grid", np.asarray(_grid_cells(height, width, STEP)), num_superpixels((height, width), STEP),
              ("jaxanom blockwise",))]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for name, labels, k, impls in cases:
            inputs = Path(folder) / f"{k}.npz"
            np.savez(inputs, anomaly=anomaly, road=road, labels=labels, k=k)
            maps, base_ms = {}, None  # the first implementation (jaxanom blockwise) is the base
            for impl in impls:
                out = str(Path(folder) / f"{k}-{impl.replace(' ', '_')}.npy")
                peak, _ = _peak_of(_EQ6_CHILD, [str(inputs), impl, out])
                ms = float(Path(out + ".ms").read_text())
                base_ms = ms if base_ms is None else base_ms
                rows.append(dict(benchmark="eq6 memory", case=f"1x{height}x{width}, {name}, K={k}", impl=impl,
                                 median_ms=ms, ms_per_frame=ms, ratio=ms / base_ms, peak_mb=peak))
                maps[impl] = np.load(out)
            peer = "numpy" if "numpy" in maps else impls[0]
            diff = max(float(np.max(np.abs(maps[i] - maps[peer]))) for i in maps)
            if diff > 1e-4:
                raise AssertionError(f"Eq. 6 implementations disagree by {diff} at K={k}")
            for row in rows[-len(impls):]:
                row["note"] = f"{source}; max |diff| vs {peer} {diff:.1e}"
    return rows


def synthesis_rows(batch: int, height: int, width: int, repeats: int) -> list[dict]:
    """The class-mean gather and the tiny SPADE generator on one batch of random 19-class maps."""
    import jax

    from jaxanom.mmf.synthesis import ClassMeanSynthesizer, SPADESynthesizer
    from jaxanom.models.spade_generator import SPADEGenerator

    semantic = jax.device_put(np.random.default_rng(batch).integers(0, 19, (batch, height, width), dtype=np.int32))
    means = ClassMeanSynthesizer(np.random.default_rng(0).random((20, 3)).astype(np.float32))
    generator = SPADEGenerator(19, nf=8, upsamples=3, hidden=32)
    spade = SPADESynthesizer(generator, jax.jit(generator.init)(jax.random.key(0, impl="rbg"), semantic[:1]))
    case = f"{batch}x{height}x{width}, C=19"
    base_ms = median_ms(lambda: means.synthesize_batch(semantic), repeats=repeats, warmup=1)
    spade_ms = median_ms(lambda: spade.synthesize_batch(semantic), repeats=repeats, warmup=1)
    return [dict(benchmark="synthesis", case=case, impl="class means", median_ms=base_ms, ms_per_frame=base_ms / batch,
                 ratio=1.0, note="gather (jit)"),
            dict(benchmark="synthesis", case=case, impl="SPADE generator", median_ms=spade_ms,
                 ms_per_frame=spade_ms / batch, ratio=spade_ms / base_ms, note="nf 8, n 3, hidden 32 (jit)")]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="128x256 frames (K = 512) instead of 256x512 (K = 2048)")
    args = parser.parse_args()
    print(environment())
    print(markdown_table(run(quick=args.quick)))
