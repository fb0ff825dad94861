"""jaxanom's own plug-ins: the one list of library modules that register its scoring methods,
training objectives and attention modules when imported.

Every registry (``method_registry``, ``objectives``, ``models.attention``) calls ``load()``
before its first look-up, so a paper's package registers what it adds by being named here once.
"""
from __future__ import annotations

import importlib

MODULES = (
    # training objectives
    "jaxanom.losses",
    "jaxanom.cudam.objective",
    "jaxanom.msaam.objective",
    # scoring methods
    "jaxanom.cudam.methods",
    "jaxanom.mmf.methods",
    "jaxanom.score_methods",
    "jaxanom.sml.methods",
    "jaxanom.void_methods",
    # attention modules
    "jaxanom.cudam.attention",
    "jaxanom.msaam.attention",
)


def load() -> None:
    """Import every module of ``MODULES`` (each registers its plug-ins; Python imports a module once)."""
    for module in MODULES:
        importlib.import_module(module)


def in_order(names, module_of) -> tuple[str, ...]:
    """``names`` (a registry's, in registration order) with jaxanom's own first, in the order of
    ``MODULES`` (``module_of(name)``: the module that registered it), whichever module a caller
    happened to import first; the others after them, as registered."""
    rank = {module: index for index, module in enumerate(MODULES)}
    return tuple(sorted(names, key=lambda name: rank.get(module_of(name), len(MODULES))))
