"""The application layer: workflows built from the library (the second of README.md's three layers).

Training runs from a config (``experiment``), config files and ``--set`` (``configs``), run
folders of imported weights (``runs``), evaluation over a dataset (``evaluate``), batches scored
by the registered methods (``scoring``), prediction on image folders (``predict``), the MMF and
off-road pipelines (``mmf_pipeline``, ``offroad_pipeline``) and their experiments
(``mmf_experiment``, ``offroad_experiment``), results tables (``reports``), output folders
(``outputs``), one function per command (``commands``) and the demos (``demos``, leaves that only
``commands.demo`` imports).
The library never imports this package, and this package never imports ``jaxanom.cli``
(``tests/project/test_layers.py``).
"""
