"""Config-as-code experiments that reproduce the structure of the papers' tables (see RESULTS.md).

One file per table (``sml_table3_table7``, ``cudam_table2``, ...), each with ``NAME``, ``TITLE``,
``rows(scale)`` and ``findings(values)``; ``python -m experiments`` runs them all.
"""
