"""Synthetic scene generation (frames/s) and the grain training pipeline (batches/s).

The peer for the pipeline is PyTorch's ``DataLoader`` over the same source and augmentation in
the calling process (``num_workers=0``), so the rows compare the loaders' own overhead; ratio =
peer time / jaxanom time. Run: ``PYTHONPATH=. python benchmarks/bench_data.py [--quick]``.
"""
from __future__ import annotations

import sys

import numpy as np

from benchmarks.timing import environment, markdown_table, median_ms, require
from jaxanom.data.synthetic import SyntheticScenes, generate
from jaxanom.data.transforms import Augment


def _generation_rows(quick: bool) -> list[dict]:
    rows = []
    for height, width in ((512, 1024), (256, 512)):
        for split in ("train", "anomaly"):
            counter = iter(range(10**9))
            ms = median_ms(lambda: generate(split, next(counter), 0, height=height, width=width),
                           repeats=5 if quick else 30, warmup=1)
            rows.append({"benchmark": "synthetic frame", "case": f"{split} {height}x{width}", "impl": "jaxanom",
                         "median_ms": ms, "note": f"{1e3 / ms:.1f} frames/s"})
    return rows


def _pipeline_rows(quick: bool) -> list[dict]:
    from jaxanom.data.pipeline import training_batches

    batch, crop = 8, (256, 256)
    source = SyntheticScenes("train", 512, seed=0, height=256, width=512)
    augment = Augment(crop_hw=crop)
    repeats = 3 if quick else 10
    rows = []
    for threads in (0, 2):
        iterator = training_batches(source, batch_size=batch, augment=augment, seed=0,
                                    process_index=0, process_count=1, num_threads=threads)
        ms = median_ms(lambda: next(iterator), repeats=repeats, warmup=2)
        rows.append({"benchmark": "train batch", "case": f"{batch}x{crop[0]}x{crop[1]} from 256x512, {threads} threads",
                     "impl": "jaxanom (grain)", "median_ms": ms, "note": f"{1e3 / ms:.2f} batches/s"})
    try:
        import torch.utils.data as torch_data
    except ImportError:
        return rows

    class _Augmented(torch_data.Dataset):
        def __len__(self):
            return len(source)

        def __getitem__(self, i):
            record = augment(source[i], np.random.default_rng([0, i]))
            return {"image": record["image"], "label": record["label"]}

    loader = iter(torch_data.DataLoader(_Augmented(), batch_size=batch, shuffle=True, num_workers=0,
                                        drop_last=True, collate_fn=lambda items: {
                                            key: np.stack([item[key] for item in items]) for key in items[0]}))
    ms = median_ms(lambda: next(loader), repeats=repeats, warmup=2)
    rows.append({"benchmark": "train batch", "case": f"{batch}x{crop[0]}x{crop[1]} from 256x512, 0 threads",
                 "impl": "torch DataLoader", "median_ms": ms, "ratio": ms / rows[0]["median_ms"],
                 "note": f"{1e3 / ms:.2f} batches/s"})
    return rows


def run(quick: bool = False) -> list[dict]:
    require("grain")  # the GPU machines have no grain: this input-pipeline benchmark is for CPU hosts
    return _generation_rows(quick) + _pipeline_rows(quick)


if __name__ == "__main__":
    print(environment())
    print(markdown_table(run(quick="--quick" in sys.argv),
                         ["benchmark", "case", "impl", "median_ms", "ratio", "note"]))
