"""Run configuration (YAML, see shared spec section 2 and ``docs/formats.md``).

:func:`load_config` reads a YAML file, :func:`config_from_dict` validates a mapping. Every
problem raises :class:`odofuse.errors.ConfigError` naming the dotted key (``sensors.gps.sigma``)
and the file; malformed YAML names the line. Top-level keys, ``robot.encoder`` and ``initial``
and every other block are validated into the frozen option dataclasses declared once in
:mod:`odofuse.declarations` (``motion``, ``initial``, ``robot.encoder``, ``log``, each
``sensors.<stream>`` by its model kind and each ``options.<estimator>``); only the drive
geometry in ``robot`` is checked by the drive itself.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from odofuse.declarations import (
    ESTIMATOR_OPTIONS,
    GRAPH_ESTIMATORS,
    EncoderOptions,
    InitialOptions,
    LogOptions,
    MotionOptions,
    estimator_options,
    sensor_options,
)
from odofuse.declarations.live import LiveOptions
from odofuse.errors import ConfigError
from odofuse.options import coerce, from_mapping
from odofuse.plugins import check_allowed, check_module_name, load_function


@dataclass(frozen=True)
class RunConfig:
    """A validated run configuration.

    ``robot`` is the drive name and geometry (SI units; ``robot["encoder"]`` an
    :class:`EncoderOptions`); ``motion`` a :class:`MotionOptions`; ``initial`` an
    :class:`InitialOptions`; ``sensors`` maps a stream name to its typed sensor options
    (:data:`odofuse.declarations.SENSOR_OPTIONS`); ``options`` maps an estimator name to its
    typed options (:meth:`estimator_options` gives any estimator's, default-filled);
    ``source`` is the config file path, for error messages. ``log`` is ``builtin:NAME`` or a
    path already resolved against the config file's folder; ``log_options`` holds the rest of
    a ``log:`` mapping (``topics`` for bags). Plain mappings given to the constructor are
    validated into the typed blocks.
    """

    log: str
    robot: dict
    motion: MotionOptions = field(default_factory=MotionOptions)
    estimator: str = "dead_reckoning"
    initial: InitialOptions = field(default_factory=InitialOptions)
    sensors: dict = field(default_factory=dict)
    output: str | None = None
    options: dict = field(default_factory=dict)
    source: str = "<config>"
    log_options: dict = field(default_factory=dict)
    plugins: tuple[str, ...] = ()
    live: LiveOptions = field(default_factory=LiveOptions)  # odofuse live (odofuse.live)

    def __post_init__(self) -> None:
        src, put = self.source, functools.partial(object.__setattr__, self)
        put("live", coerce(LiveOptions, self.live, "live", src))
        put("motion", coerce(MotionOptions, self.motion, "motion", src))
        put("initial", coerce(InitialOptions, self.initial, "initial", src))
        sensors = _mapping(self.sensors, "sensors", src)
        put("sensors", {s: _sensor(s, b, src) for s, b in sensors.items()})
        options = _mapping(self.options, "options", src)
        put("options", {k: estimator_options(k, b, src) for k, b in options.items()})
        for name in self.options:  # checks across blocks (a graph block and the sensors)
            self.estimator_options(name)
        enc = (self.robot or {}).get("encoder")
        if enc is not None and not isinstance(enc, EncoderOptions):
            put(
                "robot",
                {**self.robot, "encoder": from_mapping(EncoderOptions, enc, "robot.encoder", src)},
            )

    def unfused_note(self) -> str | None:
        """The ``note:`` line of ``odofuse run`` and ``odofuse batch`` when this run's estimator
        fuses none of the configured sensors: dead reckoning (``estimator``'s default) estimates
        from the wheels alone (a gyro serves only its gyro-vs-wheels check); None otherwise."""
        if self.estimator != "dead_reckoning" or not self.sensors:
            return None
        first, *others = FILTER_ESTIMATORS + GRAPH_ESTIMATORS
        return (
            f"note: dead_reckoning fuses none of the configured sensors ({', '.join(self.sensors)}"
            f"): `estimator: {first}` (or {', '.join(others)}) fuses them"
        )

    def estimator_options(self, estimator: str | None = None):
        """The typed options of ``estimator`` (default: this run's), default-filled if absent.

        A graph estimator's :class:`~odofuse.declarations.GraphOptions` come resolved for this
        run (:meth:`~odofuse.declarations.GraphOptions.for_run`: ``robust`` merged with the
        sensor blocks' own).
        """
        name = estimator or self.estimator
        opts = self.options.get(name) or estimator_options(name, None, self.source)
        if hasattr(opts, "for_run"):  # graph options, filters (odometry_calibration: auto)
            return opts.for_run(name, self.sensors, self.source, (self.robot or {}).get("drive"))
        return opts


def _sensor(stream, block, src: str):
    typed = dataclasses.is_dataclass(block) and not isinstance(block, type)
    return block if typed else sensor_options(str(stream), block, src)


TOP_KEYS = (
    "log",
    "robot",
    "motion",
    "estimator",
    "initial",
    "sensors",
    "output",
    "options",
    "description",
    "plugins",
    "live",
)


def _mapping(v, key: str, src: str) -> dict:
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise ConfigError(f"must be a mapping, got {type(v).__name__} {v!r}", src, key)
    for k in v:
        if not isinstance(k, str):
            raise ConfigError(f"keys must be strings, got {k!r}", src, key)
    return dict(v)


def _string(v, key: str, src: str) -> str:
    if not isinstance(v, str) or not v.strip():
        raise ConfigError(f"must be a non-empty string, got {v!r}", src, key)
    return v.strip()


def _unknown(block: dict, allowed, key: str, src: str) -> None:
    for k in block:
        if k not in allowed:
            raise ConfigError(
                f"unknown key (allowed: {', '.join(allowed)})", src, f"{key}.{k}" if key else k
            )


def _geometry_value(v, key: str, src: str):
    """Drive geometry: a finite number, a string, a bool, or a list of those."""
    if isinstance(v, list | tuple):
        return [_geometry_value(x, f"{key}[{i}]", src) for i, x in enumerate(v)]
    if isinstance(v, dict):
        raise ConfigError("a geometry value must be a number or a list", src, key)
    if isinstance(v, int | float) and not isinstance(v, bool) and not math.isfinite(float(v)):
        raise ConfigError(f"must be finite, got {v!r}", src, key)
    if v is not None and not isinstance(v, bool | str | int | float):
        raise ConfigError(f"unsupported value {v!r}", src, key)
    return v


def _resolve_log(v, src: str, base_dir: Path | None) -> tuple[str, dict]:
    opts: dict = {}
    if isinstance(v, dict):
        block = from_mapping(LogOptions, v, "log", src)
        path = block.path
        if block.topics is not None:
            opts["topics"] = {
                k: list(v) if isinstance(v, tuple) else v for k, v in block.topics.items()
            }
        if block.joints is not None:  # drive input name -> JointState joint name
            opts["joints"] = dict(block.joints)
        if block.repair is not None:  # CSV repair policy: odofuse.io.csvlog.REPAIR
            opts["repair"] = {"sort": block.repair.sort, "duplicates": block.repair.duplicates}
        if block.wheel_inputs != "position":
            opts["wheel_inputs"] = block.wheel_inputs
        limits = {"max_speed": block.max_speed, "max_yaw_rate": block.max_yaw_rate}
        if limits != {k: LogOptions.__dataclass_fields__[k].default for k in limits}:
            opts["limits"] = limits  # plausibility limits (odofuse.io.plausibility)
    else:
        path = _string(v, "log", src)
    if path.startswith("builtin:"):
        from odofuse.io.builtin import BUILTINS

        if path.removeprefix("builtin:").lower() not in BUILTINS:
            known = ", ".join(f"builtin:{b}" for b in BUILTINS)
            raise ConfigError(f"unknown built-in dataset '{path}'; known: {known}", src, "log")
        return path, opts
    p = Path(path).expanduser()
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    return str(p), opts


def _validate_robot(v, src: str) -> dict:
    robot = _mapping(v, "robot", src)
    if "drive" not in robot:
        raise ConfigError(
            "missing required value (e.g. differential, increments)", src, "robot.drive"
        )
    drive = _string(robot["drive"], "robot.drive", src)
    out = {"drive": drive}
    # The drive class itself checks the geometry's keys, presence and ranges in _check_drive.
    geometry = {
        k: _geometry_value(val, f"robot.{k}", src)
        for k, val in robot.items()
        if k not in ("drive", "encoder")
    }
    out.update(geometry)
    if robot.get("encoder") is not None:
        out["encoder"] = from_mapping(EncoderOptions, robot["encoder"], "robot.encoder", src)
    _check_drive(drive, geometry, src)
    return out


def _plugins(v, src: str) -> tuple[str, ...]:
    """The top-level ``plugins:`` list: the modules whose classes/functions may be named."""
    if v is None:
        return ()
    if not isinstance(v, list):
        raise ConfigError(f"must be a list of module names, got {type(v).__name__}", src, "plugins")
    out = []
    for i, name in enumerate(v):
        try:
            out.append(check_module_name(name))
        except ConfigError as exc:
            raise ConfigError(str(exc), src, f"plugins[{i}]") from None
    return tuple(out)


def _gate_plugins(top: dict, allowed: tuple[str, ...], src: str) -> None:
    """Refuse every ``package.module:Name`` the config names unless ``plugins:`` allows it.

    Runs before anything is validated, so that no module is imported for a config that did not
    opt in (shared spec section 5).
    """
    named = []
    robot = top.get("robot")
    if isinstance(robot, dict) and isinstance(robot.get("drive"), str):
        named.append(("robot.drive", robot["drive"], "drive"))
    if isinstance(top.get("estimator"), str):
        named.append(("estimator", top["estimator"], "estimator"))
    sensors = top.get("sensors") if isinstance(top.get("sensors"), dict) else {}
    for stream, block in sensors.items():
        if isinstance(block, dict) and "class" in block:
            named.append((f"sensors.{stream}.class", block["class"], "measurement model"))
    options = top.get("options") if isinstance(top.get("options"), dict) else {}
    named += [(f"options.{k}", k, "estimator") for k in options if ":" in str(k)]
    for key, spec, what in named:
        if ":" in str(spec):
            try:
                check_allowed(spec, allowed, what)
            except ConfigError as exc:
                raise ConfigError(str(exc), src, key) from None


def _check_estimator(name: str, src: str) -> None:
    """A built-in estimator name, or an allowed plug-in checked to be a ``run(log, config)``."""
    if ":" in name:
        try:
            load_function(name, "estimator")
        except ConfigError as exc:
            raise ConfigError(str(exc), src, "estimator") from None
    elif name not in ESTIMATOR_OPTIONS:
        raise ConfigError(
            f"unknown estimator '{name}'; known: {', '.join(ESTIMATOR_OPTIONS)}", src, "estimator"
        )


def _check_drive(drive: str, geometry: dict, src: str) -> None:
    """Let ``odofuse.drives.make_drive`` validate the drive name and geometry.

    Its errors (``ConfigError`` naming the geometry key, or ``ValueError``/``TypeError``) are
    re-raised naming ``robot.<key>`` and the config file.
    """
    try:
        from odofuse.drives import make_drive
    except ImportError:  # pragma: no cover - drives is part of the package
        return
    try:
        make_drive(drive, **geometry)
    except ConfigError as exc:
        key = exc.key or "drive"
        msg = str(exc)
        prefix = f"key '{exc.key}': " if exc.key else ""
        msg = msg.split(prefix, 1)[-1] if prefix else msg
        raise ConfigError(msg, src, f"robot.{key}") from None
    except (TypeError, ValueError) as exc:
        msg = str(exc)
        hit = [k for k in geometry if re.search(rf"\b{re.escape(k)}\b", msg)]
        raise ConfigError(msg, src, f"robot.{hit[0]}" if hit else "robot.drive") from None


FILTER_ESTIMATORS = ("ekf", "ukf", "particle")


def _check_motion_against_drive(robot: dict, motion: MotionOptions, src: str) -> None:
    """``k_r``/``k_l`` need a left/right drive; a ``k`` list needs one entry per drive input."""
    from odofuse.drives import make_drive

    geometry = {k: v for k, v in robot.items() if k not in ("drive", "encoder")}
    drive = make_drive(robot["drive"], **geometry)
    names = tuple(drive.input_names)
    for key in ("k_r", "k_l"):
        if getattr(motion, key) is not None and len(getattr(drive, "sides", ())) != len(names):
            raise ConfigError(
                f"applies to left/right wheels; drive '{robot['drive']}' has "
                f"inputs {', '.join(names)} (use k: [one per input])",
                src,
                f"motion.{key}",
            )
    for key in ("k", "var_floor", "var_rate"):
        value = getattr(motion, key)
        if isinstance(value, tuple) and len(value) != len(names):
            raise ConfigError(
                f"needs one number per drive input ({', '.join(names)}), got {len(value)}",
                src,
                f"motion.{key}",
            )
    if motion.k_theta_ds is not None and not hasattr(drive, "heading_input"):
        raise ConfigError(
            f"applies to the increments and twist drives, not '{robot['drive']}'",
            src,
            "motion.k_theta_ds",
        )
    if motion.alphas is not None:
        if not hasattr(drive, "quadratic_noise"):
            raise ConfigError(
                f"Thrun's velocity-model alphas need the increments or twist drive, "
                f"not '{robot['drive']}'",
                src,
                "motion.alphas",
            )
        try:
            drive.quadratic_noise(motion.alphas)
        except ConfigError as exc:
            raise ConfigError(str(exc).split(": ", 1)[-1], src, "motion.alphas") from None


def config_from_dict(
    d: dict, source: str = "<config>", base_dir: str | Path | None = None
) -> RunConfig:
    """Validate a configuration mapping (the parsed YAML) into a :class:`RunConfig`.

    Parameters
    ----------
    d : dict
        The configuration.
    source : str
        Where it came from (named in error messages).
    base_dir : str or Path, optional
        Folder against which a relative ``log`` path is resolved (the config file's folder).

    Raises
    ------
    ConfigError
        Naming the dotted key and ``source``.
    """
    src = source
    if not isinstance(d, dict):
        raise ConfigError("the configuration must be a mapping of keys", src)
    top = dict(d)
    _unknown(top, TOP_KEYS, "", src)
    if "log" not in top:
        raise ConfigError("missing required value (a log folder, bag or builtin:NAME)", src, "log")
    if "robot" not in top:
        raise ConfigError("missing required value (a mapping with at least 'drive')", src, "robot")
    plugins = _plugins(top.get("plugins"), src)
    _gate_plugins(top, plugins, src)
    base = Path(base_dir) if base_dir is not None else None
    log, log_options = _resolve_log(top["log"], src, base)
    estimator = (
        _string(top["estimator"], "estimator", src)
        if top.get("estimator") is not None
        else "dead_reckoning"
    )
    _check_estimator(estimator, src)
    output = None
    if top.get("output") is not None:
        out = Path(_string(top["output"], "output", src)).expanduser()
        output = str(base / out if base is not None and not out.is_absolute() else out)
    if "description" in top and top["description"] is not None:
        _string(top["description"], "description", src)
    robot = _validate_robot(top["robot"], src)
    motion = from_mapping(MotionOptions, top.get("motion"), "motion", src)
    _check_motion_against_drive(robot, motion, src)
    rates = motion.var_rate if isinstance(motion.var_rate, tuple) else (motion.var_rate,)
    if max(rates) > 0 and estimator not in FILTER_ESTIMATORS:
        raise ConfigError(
            f"the per-second floor is used by the filters ({', '.join(FILTER_ESTIMATORS)}), "
            f"not by '{estimator}' yet; use var_floor (per step)",
            src,
            "motion.var_rate",
        )
    return RunConfig(
        log=log,
        robot=robot,
        motion=motion,
        estimator=estimator,
        initial=from_mapping(InitialOptions, top.get("initial"), "initial", src),
        sensors=_mapping(top.get("sensors"), "sensors", src),
        output=output,
        options=_mapping(top.get("options"), "options", src),
        source=src,
        log_options=log_options,
        plugins=plugins,
        live=from_mapping(LiveOptions, top.get("live"), "live", src),
    )


#: Bounds of a config file (shared spec section 5): size, nesting depth, and how many nodes
#: aliases may add when expanded (a config needs a handful; an alias bomb needs billions).
MAX_CONFIG_BYTES = 1 << 20
MAX_YAML_DEPTH = 50
MAX_ALIAS_EXPANSION = 10_000


def _yaml_loader():
    """PyYAML's SafeLoader, bounded, with YAML 1.2 floats (``1e-4`` is a number).

    Refuses nesting deeper than :data:`MAX_YAML_DEPTH`, aliases that expand to more than
    :data:`MAX_ALIAS_EXPANSION` extra nodes, and duplicate keys (each a ``MarkedYAMLError``
    naming the line).
    """
    import yaml
    from yaml.constructor import ConstructorError
    from yaml.nodes import MappingNode, SequenceNode

    class Loader(yaml.SafeLoader):
        def __init__(self, stream):
            super().__init__(stream)
            self._depth = 0

        def compose_node(self, parent, index):
            self._depth += 1
            if self._depth > MAX_YAML_DEPTH:
                mark = self.peek_event().start_mark
                raise yaml.MarkedYAMLError(
                    problem=f"nested deeper than {MAX_YAML_DEPTH} levels", problem_mark=mark
                )
            try:
                return super().compose_node(parent, index)
            finally:
                self._depth -= 1

        def compose_document(self):
            node = super().compose_document()
            _check_expansion(node)
            return node

        def construct_mapping(self, node, deep=False):
            if isinstance(node, MappingNode):
                seen: dict = {}
                for key_node, _ in node.value:
                    if key_node.tag == "tag:yaml.org,2002:merge":
                        continue
                    key = self.construct_object(key_node, deep=True)
                    try:
                        first = seen.setdefault(key, key_node.start_mark)
                    except TypeError:
                        continue  # unhashable key: SafeConstructor reports it
                    if first is not key_node.start_mark:
                        raise ConstructorError(
                            None,
                            None,
                            f"duplicate key {str(key)[:40]!r} (first on line {first.line + 1})",
                            key_node.start_mark,
                        )
            return super().construct_mapping(node, deep=deep)

    def _check_expansion(root) -> None:
        """Count the nodes of the document with aliases expanded; refuse an alias bomb."""
        if root is None:
            return
        size: dict[int, int] = {}
        order, stack, distinct = [], [root], 0
        while stack:  # iterative post-order over the node graph (aliases share nodes)
            node = stack.pop()
            if id(node) in size:
                continue
            size[id(node)] = 0
            distinct += 1
            order.append(node)
            if isinstance(node, SequenceNode):
                stack.extend(node.value)
            elif isinstance(node, MappingNode):
                stack.extend(x for pair in node.value for x in pair)
        for node in reversed(order):
            if isinstance(node, SequenceNode):
                children = node.value
            elif isinstance(node, MappingNode):
                children = [x for pair in node.value for x in pair]
            else:
                children = ()
            size[id(node)] = 1 + sum(size[id(c)] for c in children)
            if size[id(node)] - distinct > MAX_ALIAS_EXPANSION:
                raise yaml.MarkedYAMLError(
                    problem=f"aliases expand to more than {MAX_ALIAS_EXPANSION} extra nodes",
                    problem_mark=node.start_mark,
                )

    float_re = re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    )
    Loader.yaml_implicit_resolvers = {
        k: [(tag, r) for tag, r in v if tag != "tag:yaml.org,2002:float"]
        for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", float_re, list("-+0123456789."))
    return Loader


def parse_yaml(text: str, source: str):
    """Parse YAML text; malformed YAML raises ConfigError naming the file and line.

    Numbers in exponent form without a dot (``1e-4``) are floats, as in YAML 1.2 (PyYAML's
    YAML 1.1 rules would read them as strings).
    """
    import yaml

    try:
        return yaml.load(text, Loader=_yaml_loader())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise ConfigError(f"malformed YAML: {where}{problem}", source) from None


def decode_utf8(raw: bytes, source: str) -> str:
    """Decode ``raw`` as UTF-8; a bad byte raises ConfigError naming its offset and line."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        col = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ConfigError(
            f"not UTF-8: byte 0x{raw[exc.start]:02x} at offset {exc.start} "
            f"(line {line}, column {col})",
            source,
        ) from None


def load_config(path: str | Path) -> RunConfig:
    """Read and validate a YAML run config; a relative ``log``/``output`` is relative to it.

    Raises
    ------
    ConfigError
        Malformed YAML (with line), unknown keys, wrong types, missing required values.
    OSError
        The file cannot be read.
    """
    path = Path(path)
    with path.open("rb") as fh:
        raw = fh.read(MAX_CONFIG_BYTES + 1)
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"larger than {MAX_CONFIG_BYTES} bytes; not a run config", str(path))
    data = parse_yaml(decode_utf8(raw, str(path)), str(path))
    if data is None:
        raise ConfigError("empty configuration file", str(path))
    if not isinstance(data, dict):
        raise ConfigError("the configuration must be a mapping of keys", str(path))
    return config_from_dict(data, str(path), path.parent)
