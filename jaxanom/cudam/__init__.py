"""CuDAM (curiosity-driven attention; docs/papers/sml-cudam-msaam.md), one paper in one package.

- ``attention``: the attention module (Eqs. 1-3), registered as the attention module ``"cudam"``;
- ``losses``: the reward (Eq. 4), the attention loss (Eq. 7) and the self-regulated lambda (Eq. 9);
- ``objective``: the training objective (Eq. 8), registered as ``"cudam"``;
- ``score``: the attention upsampling and the ensemble score (Eq. 10), the paper-equivalent tau / sigma;
- ``methods``: the ensemble as the scoring method ``"cudam"``.

``jaxanom.builtins`` names the registering modules; nothing outside this package switches on CuDAM.
"""
