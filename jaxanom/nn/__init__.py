"""Neural-network building blocks: conv-BN layers and the papers' attention modules."""
from jaxanom.nn.cudam import CuDAMAttention
from jaxanom.nn.msaam import MSAAM, best_rectangle

__all__ = ["CuDAMAttention", "MSAAM", "best_rectangle"]
