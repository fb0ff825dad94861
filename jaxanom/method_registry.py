"""Anomaly-scoring methods by name: one registry that every command, demo and experiment scores through.

A ``Method`` is a name, the inputs it needs from a batch (keys of ``INPUTS``), a pure score
function ``(inputs, options) -> (B, H, W)`` (higher = more anomalous), its options with their
defaults, and a one-line description. ``score(name, inputs, options)`` checks what the method
needs and calls it; ``check(names, provided)`` validates a whole list before any work.

Where methods come from, loaded once on first use:

- jaxanom's own: the modules ``jaxanom.builtins`` lists (``score_methods`` beside ``scores``,
  ``sml/methods``, ``cudam/methods``, ``mmf/methods``, ...), so a paper's rows sit beside its code;
- installed packages: the modules (or objects) named by the ``jaxanom.methods`` entry-point group;
- any module imported by the caller (``load_plugin``, the commands' ``--plugin MODULE``).

Each of those modules calls ``register(Method(...))`` when imported.
"""
from __future__ import annotations

import dataclasses
import importlib
import types
from typing import Any, Callable, Iterable, Mapping

from jaxanom.errors import InputError

ENTRY_POINTS = "jaxanom.methods"

# What a batch can give the methods, and how a missing input is described in an error.
INPUTS: dict[str, str] = {
    "logits": "the network's logits (B, H, W, C)",
    "stats": "SML class statistics (mean, std), each (C,)",
    "attention": "an attention map (B, H, W) upsampled to the logits' size, with attention_positions, the "
                 "map's h * w before upsampling (a network with a CuDAM module)",
    "image": "the images (B, H, W, 3) uint8 RGB at the logits' size",
    "mmf_maps": "MMF's maps (a trained MMF pipeline)",
    "void_channel": "the index of a void output among the logits' channels (a network trained with a void class)",
}

Inputs = Mapping[str, Any]
Options = Mapping[str, Any]


@dataclasses.dataclass(frozen=True)
class Method:
    """One scoring method.

    ``needs``: the keys of ``INPUTS`` it reads. ``score(inputs, options)``: float32 (B, H, W),
    higher = more anomalous, from ``inputs`` (holding at least ``needs``) and ``options`` (every
    key of ``defaults``, resolved). ``defaults``: its options and their values; a None default
    may be filled from the batch by ``resolve(inputs, options) -> options`` (e.g. a weight that
    depends on the attention map's size). ``description``: one line, shown by ``--help``.
    """

    name: str
    needs: frozenset[str]
    score: Callable[[Inputs, Options], Any]
    description: str
    defaults: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    resolve: Callable[[Inputs, Options], Options] | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name or "," in self.name or self.name != self.name.strip():
            raise ValueError(f"name: expected a non-empty name without commas or surrounding spaces, got {self.name!r}")
        needs = frozenset(self.needs)
        if unknown := sorted(needs - set(INPUTS)):
            raise ValueError(f"needs of {self.name}: expected keys of INPUTS {sorted(INPUTS)}, got {unknown}")
        if not callable(self.score) or (self.resolve is not None and not callable(self.resolve)):
            raise ValueError(f"score, resolve of {self.name}: expected functions (inputs, options)")
        if not isinstance(self.description, str) or not self.description.strip() or "\n" in self.description.strip():
            raise ValueError(f"description of {self.name}: expected one line, got {self.description!r}")
        object.__setattr__(self, "needs", needs)
        object.__setattr__(self, "defaults", types.MappingProxyType(dict(self.defaults)))

    def options(self, inputs: Inputs, given: Options | None = None) -> dict:
        """This method's options: its defaults, overridden by the keys of ``given`` it declares
        (a None value keeps the default), then resolved against ``inputs``."""
        given = given or {}
        options = {k: given[k] if given.get(k) is not None else v for k, v in self.defaults.items()}
        return dict(self.resolve(inputs, options)) if self.resolve is not None else options


_METHODS: dict[str, Method] = {}
_ORIGIN: dict[str, str] = {}  # name -> the module that registered it, for conflict messages
_loaded = False


def register(method: Method) -> Method:
    """Add ``method``; ValueError if another method already has its name. Returns it."""
    if not isinstance(method, Method):
        raise ValueError(f"method: expected a jaxanom.method_registry.Method, got {type(method).__name__}")
    origin = getattr(method.score, "__module__", "?")
    if method.name in _METHODS and _METHODS[method.name] != method:
        raise ValueError(f"method {method.name!r}: already registered by {_ORIGIN[method.name]}; "
                         f"{origin} cannot register another under the same name")
    _METHODS[method.name] = method
    _ORIGIN[method.name] = origin
    return method


def get(name: str) -> Method:
    """The method called ``name``; ValueError naming it and the known names otherwise."""
    _load()
    if name not in _METHODS:
        raise InputError("methods", f": expected names from {', '.join(_METHODS)}; got unknown {name!r}")
    return _METHODS[name]


def names() -> tuple[str, ...]:
    """Every registered name: jaxanom's own first, then installed plug-ins', then loaded modules'."""
    _load()
    return tuple(_METHODS)


def check(method_names: Iterable[str], provided: Iterable[str], options: Options | None = None) -> tuple[str, ...]:
    """Validate a list of methods against the inputs a batch will provide; returns the names as a tuple.

    ValueError in one line for: an empty list, unknown names (listing the known ones), an input
    some methods need that ``provided`` lacks (naming the input and those methods), or an option
    in ``options`` that no known method declares.
    """
    selected = tuple(method_names)
    _load()
    unknown = [n for n in selected if n not in _METHODS]
    if unknown or not selected:
        raise InputError("methods", f": expected names from {', '.join(_METHODS)}; got {list(selected)}")
    provided = set(provided)
    for key in INPUTS:  # the first missing input, with every method that needs it
        if key not in provided and (missing := [n for n in selected if key in _METHODS[n].needs]):
            raise InputError("methods", f"{missing} need {INPUTS[key]}; none were given")
    declared = {k for m in _METHODS.values() for k in m.defaults}
    if stray := sorted(set(options or {}) - declared):
        raise InputError("options", f": expected names from {sorted(declared)}, got {stray}")
    return selected


def score(name: str, inputs: Inputs, options: Options | None = None):
    """Scores float32 (B, H, W) of method ``name`` for ``inputs`` (keys of ``INPUTS``; batch-first
    arrays; a None value counts as absent), higher = more anomalous. ``options``: values of the
    options methods declare (keys this method does not declare are ignored, so one mapping can
    serve many methods)."""
    method = get(name)
    check((name,), given(inputs), options)
    return method.score(inputs, method.options(inputs, options))


def given(inputs: Inputs) -> set[str]:
    """The names of ``inputs`` that hold a value (None counts as not given)."""
    return {key for key, value in inputs.items() if value is not None}


def load_plugin(module: str) -> None:
    """Import ``module`` (a dotted name on ``sys.path``), which registers its methods; jaxanom's
    own are registered first, so a plug-in cannot take one of their names. ModuleNotFoundError
    when it is not found; errors raised inside it propagate."""
    _load()
    importlib.import_module(module)


def _load() -> None:
    """Register jaxanom's own methods and the installed plug-ins' (once)."""
    global _loaded
    if _loaded:
        return
    from jaxanom import builtins

    builtins.load()
    from importlib.metadata import entry_points

    for entry in entry_points(group=ENTRY_POINTS):
        try:
            entry.load()
        except Exception as error:
            raise ImportError(f"the {ENTRY_POINTS} entry point {entry.name} = {entry.value} "
                              f"({entry.dist.name if entry.dist else 'unknown distribution'}) failed to load: "
                              f"{type(error).__name__}: {error}") from error
    _loaded = True
