"""Anomaly-scoring methods by name: one registry that every command, demo and experiment scores through.

A ``Method`` is a name, the inputs it needs from a batch (keys of ``INPUTS``), a pure score
function ``(inputs, options) -> (B, H, W)`` (higher = more anomalous), its options with their
defaults, and a one-line description. ``score(name, inputs, options)`` checks what the method
needs and calls it; ``check(names, provided)`` validates a whole list before any work.

Where methods come from, loaded once on first use:

- jaxanom's own: the modules ``jaxanom.builtins`` lists (``score_methods`` beside ``scores``,
  ``sml/methods``, ``cudam/methods``, ``mmf/methods``, ...), so a paper's rows sit beside its code;
- installed packages: the modules (or objects) named by the ``jaxanom.methods`` entry-point group,
  unless the environment variable ``JAXANOM_DISABLE_ENTRY_POINTS`` is set (to anything but
  ``""`` or ``0``); one that fails to load is left out and named only when a name it might have
  provided is asked for (``get``, ``check``), so it breaks no command that does not need it;
- any module imported by the caller (``load_plugin``, the commands' ``--plugin MODULE``).

Each of those modules calls ``register(Method(...))`` when imported. The registry is a
``jaxanom.registry.Registry`` (``METHODS``), the type every kind of plug-in uses.

Post-processing composes by name: ``"NAME+POST"`` is method NAME's scores through the
post-processor POST, one that a module registered with ``register_post(Post(...))`` (SML's
``post``, ``suppress`` and ``smooth``: ``"energy+post"``), applied left to right
(``"NAME+POST1+POST2"``). ``+`` never occurs in a registered name (``registry.NAME_RULE``), so a
composed name is never ambiguous; ``get`` and ``check`` resolve it, ``names()`` lists registered
methods only.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import sys
import types
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from jaxanom import builtins, registry
from jaxanom.errors import InputError
from jaxanom.registry import DISABLE_ENTRY_POINTS, NAME

__all__ = ["DISABLE_ENTRY_POINTS", "ENTRY_POINTS", "INPUTS", "METHODS", "Method", "NAME", "NAME_RULE", "Post",
           "call", "check", "check_finite", "check_output", "get", "given", "implementation", "is_name", "load_plugin",
           "names", "posts", "read_only", "register", "register_post", "score"]

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

# A method's name becomes a folder or file name of the commands' outputs (``npy/<method>/``,
# ``scores/<method>.npy``): a registered name follows ``registry.NAME_RULE``, so never a path; a
# composed name joins such names with ``+`` (``msp+post``), still no path.
NAME_RULE = f"{registry.NAME_RULE}, composed with '+'"


def is_name(text) -> bool:
    """Whether ``text`` may name a method (``NAME_RULE``): a registered entry's name
    (``registry.is_name``), or such names joined by ``+`` (a method composed with
    post-processors); never a path."""
    return isinstance(text, str) and all(registry.is_name(part) for part in text.split("+"))


@dataclasses.dataclass(frozen=True)
class Method:
    """One scoring method.

    ``needs``: the keys of ``INPUTS`` it reads. ``score(inputs, options)``: float32 (B, H, W),
    higher = more anomalous, from ``inputs`` (holding at least ``needs``) and ``options`` (every
    key of ``defaults``, resolved). ``defaults``: its options and their values; a None default
    may be filled from the batch by ``resolve(inputs, options) -> options`` (e.g. a weight that
    depends on the attention map's size). ``types``: each option's type, as a config field's
    (``float``, ``int | None``, ``tuple[int, ...]``; ``jaxanom.config_codec``), by which the
    commands read ``--set methods.NAME.OPTION=VALUE``; default: the type of its default value
    (a None default needs its type declared). ``description``: one line, shown by ``--help``.
    """

    name: str
    needs: frozenset[str]
    score: Callable[[Inputs, Options], Any]
    description: str
    defaults: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    resolve: Callable[[Inputs, Options], Options] | None = None
    types: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if not is_name(self.name):
            raise ValueError(f"name: expected {NAME_RULE}, got {self.name!r}")
        needs = frozenset(self.needs)
        if unknown := sorted(needs - set(INPUTS)):
            raise ValueError(f"needs of {self.name}: expected keys of INPUTS {sorted(INPUTS)}, got {unknown}")
        if not callable(self.score) or (self.resolve is not None and not callable(self.resolve)):
            raise ValueError(f"score, resolve of {self.name}: expected functions (inputs, options)")
        if not isinstance(self.description, str) or not self.description.strip() or "\n" in self.description.strip():
            raise ValueError(f"description of {self.name}: expected one line, got {self.description!r}")
        object.__setattr__(self, "needs", needs)
        object.__setattr__(self, "defaults", types.MappingProxyType(dict(self.defaults)))
        declared = dict(self.types)
        if stray := sorted(set(declared) - set(self.defaults)):
            raise ValueError(f"types of {self.name}: expected types of options in defaults, got {stray}")
        for option, default in self.defaults.items():
            if option not in declared and default is None:
                raise ValueError(f"types of {self.name}: option {option!r} has a None default; declare its type "
                                 "(e.g. types={" + repr(option) + ": float | None})")
            declared.setdefault(option, type(default))
        object.__setattr__(self, "types", types.MappingProxyType(declared))
        self.checked(self.defaults)  # each default is of its type

    def checked(self, given: Options) -> dict:
        """``given`` (option -> value) with each host value read as its declared type (an int for a
        float becomes a float; arrays, traced values included, pass as they are); InputError naming
        ``options`` and ``methods.<name>.<option>`` for an option it does not declare or a value not
        of its type."""
        from jaxanom.config_codec import ConfigError, decode, describe, encode

        values = {}
        for option, value in given.items():
            where = f"methods.{self.name}.{option}"
            if option not in self.types:
                raise InputError("options", f": {where}: method {self.name!r} has no option {option!r}; its options: "
                                 f"{', '.join(self.types) or 'none'}")
            if hasattr(value, "shape"):  # an array (a traced hyperparameter): its type is the caller's business
                values[option] = value
                continue
            try:
                values[option] = decode(self.types[option], encode(value), where)
            except (ConfigError, TypeError):
                raise InputError("options", f": {where}: expected {describe(self.types[option])}, got {value!r}") from None
        return values

    def unresolved(self, given: Options | None = None) -> dict:
        """This method's options before any batch: its defaults, overridden by the keys of
        ``given`` it declares (a None value keeps the default)."""
        given = given or {}
        return {k: given[k] if given.get(k) is not None else v for k, v in self.defaults.items()}

    def options(self, inputs: Inputs, given: Options | None = None) -> dict:
        """This method's options: ``unresolved(given)``, then resolved against ``inputs``."""
        options = self.unresolved(given)
        return dict(self.resolve(inputs, options)) if self.resolve is not None else options


@dataclasses.dataclass(frozen=True)
class Post:
    """A post-processor any method composes with as ``"NAME+<name>"``: ``apply(scores, inputs)``
    maps a method's (B, H, W) scores to (B, H, W) scores, reading the batch's ``needs`` (keys of
    ``INPUTS``) from ``inputs``. ``description``: one line, following the method's in the composition."""

    name: str
    needs: frozenset[str]
    apply: Callable[[Any, Inputs], Any]
    description: str


_POSTS: dict[str, Post] = {}


def register_post(post: Post) -> Post:
    """Add ``post`` under its name (a name without ``+``); ValueError if another has it. Returns it."""
    if not isinstance(post, Post) or not post.name or "+" in post.name or "," in post.name:
        raise ValueError(f"post: expected a Post named without '+' or ',', got {post!r}")
    if post.name in _POSTS and _POSTS[post.name] != post:
        raise ValueError(f"post-processor {post.name!r}: already registered")
    _POSTS[post.name] = post
    return post


def _composed(name: str) -> Method | None:
    """The method ``"BASE+POST1+POST2..."`` (each POST applied in turn), or None if ``name`` is
    not of that form with a registered BASE and registered POSTs."""
    base, *posts = name.split("+")
    if not posts or base not in METHODS.entries or any(p not in _POSTS for p in posts):
        return None
    method = METHODS.entries[base]
    for post in (_POSTS[p] for p in posts):
        inner = method.score
        method = dataclasses.replace(
            method, name=f"{method.name}+{post.name}", needs=method.needs | post.needs,
            score=lambda inputs, options, inner=inner, post=post: post.apply(inner(inputs, options), inputs),
            description=f"{method.description}; then {post.description}")
    return method


METHODS: registry.Registry[Method] = registry.Registry("method", ENTRY_POINTS, lambda: builtins.MODULES)


def register(method: Method) -> Method:
    """Add ``method`` (whose name ``Method`` has checked: a name, never a path); ValueError if
    another method already has its name. Returns it."""
    if not isinstance(method, Method):
        raise ValueError(f"method: expected a jaxanom.method_registry.Method, got {type(method).__name__}")
    return METHODS.add(method.name, method, sys._getframe(1).f_globals.get("__name__", "?"))  # the caller's module


def implementation(name: str) -> str:
    """A fingerprint of method ``name``'s code: SHA-256 (hex) of the source files of the modules
    that registered it and define its ``score`` and ``resolve`` (a plug-in's module, or jaxanom's
    own ``*methods.py``; a module without a file counts by its name only), and, for a composed
    ``"NAME+POST"``, those defining each post's ``apply``. Another plug-in
    registering the name, or an edit of its module (a default option included), changes it."""
    method = get(name)
    base, *post_names = name.split("+")  # a composed method: its base's code and each post's
    modules = {METHODS.origin(base)}
    for function in (METHODS.entries[base].score, method.resolve, *(_POSTS[p].apply for p in post_names)):
        while isinstance(function, functools.partial):
            function = function.func
        if function is not None:
            modules.add(getattr(function, "__module__", None) or type(function).__module__)
    digest = hashlib.sha256()
    for module in sorted(modules):
        file = getattr(sys.modules.get(module), "__file__", None)
        digest.update(f"{module}\n".encode())
        if file and Path(file).is_file():
            digest.update(Path(file).read_bytes())
    return digest.hexdigest()


def get(name: str) -> Method:
    """The method called ``name`` (registered, or composed ``"NAME+POST"``); ValueError naming it
    and the known names otherwise."""
    method = METHODS.find(name) or _composed(name)
    if method is None:
        raise InputError("methods", f": expected names from {', '.join(METHODS.names())} (each may end in "
                                    f"{_post_suffixes()}); got unknown {name!r}{METHODS.broken_note()}")
    return method


def names() -> tuple[str, ...]:
    """Every registered name: jaxanom's own first, then installed plug-ins', then loaded modules'."""
    return METHODS.names()


def check(method_names: Iterable[str], provided: Iterable[str],
          options: Mapping[str, Options] | None = None) -> tuple[str, ...]:
    """Validate a list of methods against the inputs a batch will provide; returns the names as a tuple.

    ``options``: ``{method: {option: value}}`` for some of the methods. ValueError in one line for:
    an empty list, unknown names (listing the known ones), an input some methods need that
    ``provided`` lacks (naming the input and those methods), options of a method not in the list,
    or an option its method does not declare or a value not of its type (``Method.checked``).
    """
    selected = tuple(method_names)
    methods = {n: METHODS.find(n) or _composed(n) for n in selected}
    if None in methods.values() or not selected:
        raise InputError("methods", f": expected names from {', '.join(METHODS.names())} (each may end in "
                                    f"{_post_suffixes()}); got {list(selected)}"
                                    f"{METHODS.broken_note() if None in methods.values() else ''}")
    provided = set(provided)
    for key in INPUTS:  # the first missing input, with every method that needs it
        if key not in provided and (missing := [n for n in selected if key in methods[n].needs]):
            raise InputError("methods", f"{missing} need {INPUTS[key]}; none were given")
    options = options or {}
    if not isinstance(options, Mapping) or not all(isinstance(given, Mapping) for given in options.values()):
        raise InputError("options", f": expected a mapping of method names to their options, got {options!r}")
    if stray := [name for name in options if name not in selected]:
        raise InputError("options", f": options of {stray}, which are not among the methods {list(selected)}")
    for name, given in options.items():
        methods[name].checked(given)
    return selected


def score(name: str, inputs: Inputs, options: Options | None = None):
    """Scores float32 (B, H, W) of method ``name`` for ``inputs`` (keys of ``INPUTS``; batch-first
    arrays; a None value counts as absent), higher = more anomalous. ``options``: values of the
    options methods declare (keys this method does not declare are ignored, so one mapping can
    serve many methods)."""
    method = get(name)
    options = {key: value for key, value in (options or {}).items() if key in method.defaults}
    check((name,), given(inputs), {name: options})
    return call(method, inputs, options)[0]


def call(method: Method, inputs: Inputs, options: Options | None = None) -> tuple[Any, dict]:
    """``(scores, used)``: ``method``'s scores of ``inputs`` and its options (``Method.options`` of
    ``options``), behind the boundary every command scores through: the method gets its own
    shallow copy of ``inputs`` with read-only NumPy arrays (what one method does to them cannot
    change the next one's scores), and what it returns is checked (``check_output``)."""
    own = read_only(inputs)
    used = method.options(own, options)
    scores = method.score(own, used)
    check_output(method.name, scores, inputs)
    return scores, used


def read_only(value):
    """``value`` with every NumPy array in it (in dicts, lists, tuples) a read-only view, and its
    dicts and lists copies; other values as they are (jax arrays are immutable)."""
    import numpy as np

    if isinstance(value, np.ndarray):
        view = value.view()
        view.flags.writeable = False
        return view
    if isinstance(value, Mapping):
        return {key: read_only(item) for key, item in value.items()}
    if type(value) in (tuple, list):
        return type(value)(read_only(item) for item in value)
    return value


def check_output(name: str, scores, inputs: Inputs) -> None:
    """InputError naming method ``name`` unless ``scores`` is an array (B, H, W) of the batch
    ``inputs`` (the logits' first three sizes) with a floating dtype. Shapes and dtypes only: no
    value is read, so it holds inside ``jax.jit``; finiteness is ``check_finite``'s, where the
    values reach the host."""
    import jax.numpy as jnp

    if not (hasattr(scores, "shape") and hasattr(scores, "dtype")):
        raise InputError("methods", f": method {name!r} returned {type(scores).__name__}; expected an array (B, H, W)")
    logits = inputs.get("logits")
    expected = tuple(logits.shape[:3]) if logits is not None else None
    if len(scores.shape) != 3 or (expected is not None and tuple(scores.shape) != expected):
        raise InputError("methods", f": method {name!r} returned scores of shape {tuple(scores.shape)}; expected "
                         f"(B, H, W) = {expected or '3 dimensions'}, the batch's")
    if not jnp.issubdtype(scores.dtype, jnp.floating):
        raise InputError("methods", f": method {name!r} returned scores of dtype {scores.dtype}; expected a floating "
                         "dtype (float32)")


def check_finite(name: str, scores, labels=None, where: str = "") -> None:
    """InputError naming method ``name`` when ``scores`` (B, H, W), NumPy or jax, hold NaN or
    +-inf on pixels whose ``labels`` are not void (255), or on any pixel without ``labels``;
    ``where``: the frames, for the message (e.g. ``" of frame 12"``). Reads one count from the
    device for a jax array."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    xp = jnp if isinstance(scores, jax.Array) else np
    bad = ~xp.isfinite(scores)
    if labels is not None:
        bad = bad & (xp.asarray(labels) != 255)
    if count := int(bad.sum()):
        pixels = "non-void pixels" if labels is not None else "pixels"
        raise InputError("methods", f": method {name!r} returned {count} NaN or infinite scores on {pixels}{where}; "
                         "expected finite scores")


def posts() -> tuple[Post, ...]:
    """Every registered post-processor (``"NAME+<post>"`` composes it with any method)."""
    METHODS.load()
    return tuple(_POSTS.values())


def _post_suffixes() -> str:
    return ", ".join("+" + p for p in _POSTS)


def given(inputs: Inputs) -> set[str]:
    """The names of ``inputs`` that hold a value (None counts as not given)."""
    return {key for key, value in inputs.items() if value is not None}


def load_plugin(module: str) -> None:
    """Import ``module`` (a dotted name on ``sys.path``), which registers its methods (and entries
    of other kinds); jaxanom's own are registered first (``registry.load_plugin``), so a plug-in
    cannot take one of their names. ``registry.PluginError`` (a ValueError) in one line when it is
    not found or its import raises."""
    METHODS.load()
    registry.load_plugin(module)
