"""Training: state, optimizer, pure train/eval steps, data-parallel sharding, checkpoints, the step
loop every trainer runs (``run_loop``), the segmenter's trainer (``segmenter``: ``TrainConfig``, ``train``).

Import the pieces from their modules (``jaxanom.train.segmenter.train``, ``jaxanom.train.step``, ...);
this package file imports nothing, so ``import jaxanom.train.step`` stays light.
"""
