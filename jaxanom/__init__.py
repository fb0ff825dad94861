"""jaxanom: finding unexpected obstacles on the road, in JAX/Flax.

Submodules load on demand (``import jaxanom.sml``, ``jaxanom.metrics``, ...), so importing the
package itself pulls in nothing heavy.
"""

__version__ = "0.1.0"
