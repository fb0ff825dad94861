"""Training: state, optimizer, pure train/eval steps, data-parallel sharding, checkpoints, the step
loop every trainer runs (``run_loop``), the segmenter's trainer (``loop``).

Import the pieces from their modules (``jaxanom.train.loop.train``, ``jaxanom.train.step``, ...);
this package file imports nothing, so ``import jaxanom.train.step`` stays light.
"""
