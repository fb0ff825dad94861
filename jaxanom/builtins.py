"""jaxanom's own plug-ins: the one list of library modules that register its scoring methods,
training objectives, attention modules, evaluators and evaluation protocols when imported.

Every registry (``method_registry.METHODS``, ``objectives.OBJECTIVES``, ``models.attention.ATTENTION_MODULES``,
``metrics.evaluator.EVALUATORS``, ``protocols.PROTOCOLS``, each a ``jaxanom.registry.Registry``)
imports them before its first look-up and lists their names first, in this order; so a paper's
package registers what it adds by being named here once.
"""
from __future__ import annotations

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
    # evaluators (dataset metrics by name)
    "jaxanom.metrics.evaluator",
    # evaluation protocols
    "jaxanom.protocols",
)

