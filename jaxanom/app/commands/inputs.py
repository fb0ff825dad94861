"""What the commands read besides their data: method names, plug-ins, SML statistics, config
files and ``NAME=VALUE`` overrides of a config's fields."""
from __future__ import annotations

from pathlib import Path

from jaxanom.errors import InputError, reading

DEFAULT_METHODS = ("msp", "max_logit", "entropy", "energy", "sml", "sml_post")


def method_names(methods: str | None, default: tuple[str, ...] = DEFAULT_METHODS) -> tuple[str, ...]:
    """Comma-separated ``methods`` as a tuple (None: ``default``); InputError naming ``methods`` for
    one that is not a name (``method_registry.NAME_RULE``) or is given twice: names become output paths."""
    from jaxanom.method_registry import NAME_RULE, is_name

    names = tuple(methods.split(",")) if methods else tuple(default)
    if bad := [name for name in names if not is_name(name)]:
        raise InputError("methods", f": expected names of {NAME_RULE}, never a path; got {', '.join(map(repr, bad))}")
    if twice := sorted({name for name in names if names.count(name) > 1}):
        raise InputError("methods", f": expected each method once (one output each), got {', '.join(map(repr, twice))} twice")
    return names


def evaluator_names(evaluators: str | None) -> tuple[str, ...]:
    """Comma-separated ``evaluators`` (``jaxanom.metrics.evaluator``, a plug-in's included) as a
    tuple (None: none), each looked up: InputError naming ``evaluators`` for a name given twice or
    unknown (listing the known ones). Call it after the plug-ins are loaded."""
    from jaxanom.metrics.evaluator import get_evaluator

    names = tuple(evaluators.split(",")) if evaluators else ()
    if twice := sorted({name for name in names if names.count(name) > 1}):
        raise InputError("evaluators", f": expected each evaluator once, got {', '.join(map(repr, twice))} twice")
    for name in names:
        get_evaluator(name)
    return names


def own_entries(kind: str) -> str:
    """jaxanom's own ``"protocols"`` or ``"evaluators"``, ``name: description`` joined by ``"; "``,
    for ``--help``: what their modules registered when imported, with no plug-in loaded, so an
    installed plug-in that fails to load breaks no help (a plug-in's entries are found when the
    command runs)."""
    if kind == "protocols":
        from jaxanom.protocols import PROTOCOLS as entries
    else:
        from jaxanom.metrics.evaluator import EVALUATORS as entries
    return "; ".join(f"{name}: {entry.description}" for name, entry in entries.entries.items()
                     if entries.plugin_module(name) is None)


def load_plugins(plugins) -> None:
    """Import the plug-in modules, which register their methods, objectives (any kind of entry) on
    import. InputError naming ``plugins`` and the module, in one line, for: a name that is not a
    module's dotted name (a file path, ""), a module not found, one whose import raises (a name it
    registers already taken, a built-in's included; a dependency missing; any bug), with where it
    raised (``jaxanom.app.configs.load_plugin``)."""
    from jaxanom.app.configs import load_plugin
    from jaxanom.registry import PluginError, is_module_name

    for module in plugins:
        if not is_module_name(module):
            file = Path(str(module))
            hint = (f" (for this file: PYTHONPATH={file.parent} and {{plugins}} {file.stem})"
                    if file.suffix == ".py" and file.stem.isidentifier() else "")
            raise InputError("plugins", f" {module!r}: expected a module's dotted name (e.g. my_scores or "
                             f"package.module), importable from the Python path; not a file{hint}",
                             mentions=("plugins",))
        try:
            load_plugin(module)
        except PluginError as error:
            raise InputError("plugins", f" {error}") from None


OPTION_PREFIX = "methods."  # --set methods.METHOD.OPTION=VALUE: an option of a method


def split_overrides(overrides) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``overrides`` (``--set``) as ``(options of methods, the others)``: those of
    ``"methods.METHOD.OPTION=VALUE"``, and the config fields' ``"dotted.name=VALUE"``, each in order."""
    methods = tuple(o for o in overrides if o.partition("=")[0].strip().startswith(OPTION_PREFIX))
    return methods, tuple(o for o in overrides if o not in methods)


def method_options(names, overrides=(), **aliases) -> dict:
    """``{method: {option: value}}`` for the methods ``names``: each alias given (not None; e.g.
    ``cudam_sigma`` of ``--cudam-sigma``) set for every method of ``names`` that declares that
    option, then each ``"methods.METHOD.OPTION=VALUE"`` of ``overrides`` (``--set``; see
    ``split_overrides``) with VALUE read as the option's declared type (``Method.types``, as
    ``--set`` reads a config field). InputError naming ``overrides``, in one line naming the
    method and option: a method not among ``names``, an option it does not declare, a value not
    of its type."""
    from jaxanom.config_codec import ConfigError, parse
    from jaxanom.method_registry import get

    options: dict[str, dict] = {}
    for option, value in aliases.items():
        if value is not None:
            for name in names:
                if option in get(name).defaults:
                    options.setdefault(name, {})[option] = value
    for assignment in overrides:
        target, equals, text = assignment.partition("=")
        # the last dot: a method's name may hold dots (energy.t5), an option's never does
        method, dot, option = target.strip().removeprefix(OPTION_PREFIX).rpartition(".")
        if not (target.strip().startswith(OPTION_PREFIX) and equals and dot and method and option):
            raise InputError("overrides", f": expected methods.METHOD.OPTION=VALUE (e.g. methods.energy.temperature=2), "
                             f"got {assignment!r}")
        if method not in names:
            raise InputError("overrides", f" {target.strip()}: method {method!r} is not among the methods scored "
                             f"({', '.join(names)}; {{methods}})", mentions=("methods",))
        declared = get(method).types
        if option not in declared:
            raise InputError("overrides", f" {target.strip()}: method {method!r} has no option {option!r}; its options: "
                             f"{', '.join(declared) or 'none'}")
        try:
            options.setdefault(method, {})[option] = parse(declared[option], text, target.strip())
        except ConfigError as error:
            raise InputError("overrides", f" {error} (an option of method {method!r})") from None
    return options


def read_stats(path: str | None):
    """``(mean, std)`` from a statistics .npz, or None for None; prints the frames they were fitted on."""
    if path is None:
        return None
    from jaxanom.sml import load_stats as load, load_stats_info

    with reading("stats", path):
        mean, std, _ = load(path)
        frames = load_stats_info(path)["frames"]
    print(f"SML statistics {path}: {fitted_on(frames)}")
    return mean, std


def fitted_on(frames: dict | None) -> str:
    """The frames a statistics file records (``sml.save_stats``'s ``frames``), in words."""
    if frames is None:
        return "frames not recorded (a file written before fit-stats recorded them)"
    where = f" in {frames['folder']}" if frames.get("folder") else ""
    height, width = frames["size"]
    return f"fitted on {frames['count']} frames of {frames['set']}{where} at {height}x{width}"


def read_config(path: str, cls, variable: str = "config"):
    """The ``cls`` of the config file ``path`` (JSON, or Python defining ``variable``; see
    ``jaxanom.app.configs``); InputError naming ``config``, the file and the field's dotted name."""
    from jaxanom.app.configs import ConfigError, load_config

    try:
        return load_config(path, cls, variable)
    except ConfigError as error:
        raise InputError("config", str(error)) from None


def with_overrides(config, overrides=()):
    """``config`` with each ``"dotted.name=VALUE"`` of ``overrides`` applied (``--set``), checked whole
    before any work; InputError naming ``overrides`` and the field's dotted name."""
    from jaxanom.app.configs import ConfigError, override

    try:
        return override(config, overrides)
    except ConfigError as error:
        raise InputError("overrides", str(error)) from None


def check_stats_classes(mean_std, stats: str, network, variables, size, protocol=None) -> None:
    """InputError naming ``stats`` unless its statistics have one class per logit the methods see:
    every output of ``network`` (``size``: an (h, w) it takes; shapes only), or those ``protocol``
    (a ``jaxanom.protocols.Protocol``) keeps; before the first frame is scored."""
    from jaxanom.app.predict import logits_shape
    from jaxanom.sml import load_stats_info

    outputs = logits_shape(network, variables, tuple(size))[-1]
    seen, have = protocol.classes(outputs) if protocol else outputs, len(mean_std[0])
    if have == seen:
        return
    fitted = load_stats_info(stats)["channels"] or {}
    if seen < outputs:
        raise InputError("stats", f"{stats}: has {have} classes, the methods see {seen} (the network's {outputs} "
                         f"outputs less the void output, which protocol {protocol.name} drops); fit them with "
                         f"fit-stats --protocol {protocol.name}")
    if fitted.get("void_dropped"):
        raise InputError("stats", f"{stats}: has {have} classes, fitted without the void output (fit-stats "
                         f"--protocol {fitted['protocol']}), the methods see all {outputs} outputs here; use them with "
                         f"evaluate --protocol {fitted['protocol']}, or fit them without --protocol")
    raise InputError("stats", f"{stats}: has {have} classes, the network's logits {outputs}")
