"""Neural-network building blocks: conv-BN layers, BatchNorm, SPP, AFC and SPADE (the papers' attention
modules live in their packages, ``jaxanom.cudam`` and ``jaxanom.msaam``)."""
