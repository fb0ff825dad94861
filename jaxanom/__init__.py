"""jaxanom: finding unexpected obstacles on the road, in JAX/Flax.

Submodules load on demand (``import jaxanom.sml``, ``jaxanom.metrics``, ...), so importing the
package itself pulls in nothing heavy.
"""

__version__ = "0.1.0"


def __getattr__(name: str):
    # ``jaxanom.validate_values`` without importing JAX with the package
    if name == "validate_values":
        from jaxanom._validate import validate_values

        return validate_values
    raise AttributeError(f"module 'jaxanom' has no attribute {name!r}")
