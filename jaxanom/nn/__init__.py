"""Neural-network building blocks: conv-BN layers and the papers' attention modules."""
from jaxanom.nn.cudam import CuDAMAttention

__all__ = ["CuDAMAttention"]
