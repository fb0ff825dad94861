"""The application layer: workflows built from the library (the second of README.md's three layers).

Training runs from a config (``experiment``), run folders of imported weights (``runs``),
evaluation over a dataset (``evaluate``), batches scored by the registered methods
(``scoring``), prediction on image folders (``predict``), the MMF and off-road pipelines
(``mmf_pipeline``, ``offroad_pipeline``), results tables (``reports``) and the demos (``demos``). The library never
imports this package, and this package never imports ``jaxanom.cli`` (``tests/test_layers.py``).
"""
