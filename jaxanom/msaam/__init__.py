"""MSAAM (multi-scale adaptive attention; docs/papers/sml-cudam-msaam.md), one paper in one package.

- ``attention``: the attention module (Eqs. 1-6, 8-12), registered as the attention module ``"msaam"``;
- ``objective``: its loss (Eq. 7) and training objective, registered as ``"msaam"``.

``jaxanom.builtins`` names the registering modules; nothing outside this package switches on MSAAM.
"""
