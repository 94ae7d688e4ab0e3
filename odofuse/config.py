"""Run configuration (YAML, see shared spec section 2 and ``docs/formats.md``).

:func:`load_config` reads a YAML file, :func:`config_from_dict` validates a mapping. Every
problem raises :class:`odofuse.errors.ConfigError` naming the dotted key (``sensors.gps.sigma``)
and the file; malformed YAML names the line. Top-level keys, ``robot.encoder`` and ``initial``
are closed sets; the inner keys of ``motion``, ``sensors.<name>`` and ``options.<estimator>``
are open (back ends add their own), but typed: a key that is known to be a number must be a
number, and any value there must be a number, a string, a boolean or a list of those.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from odofuse.errors import ConfigError


@dataclass(frozen=True)
class RunConfig:
    """A validated run configuration.

    ``robot``/``motion``/``initial`` are the validated YAML blocks (plain dicts, SI units);
    ``sensors`` maps a stream name to its sensor block; ``options`` maps an estimator name to its
    own option block (e.g. ``options: {ekf: {late_window: 0.5}}``); ``source`` is the config
    file path, for error messages. ``log`` is ``builtin:NAME`` or a path already resolved
    against the config file's folder; ``log_options`` holds the rest of a ``log:`` mapping
    (``topics`` for bags).
    """

    log: str
    robot: dict
    motion: dict = field(default_factory=dict)
    estimator: str = "dead_reckoning"
    initial: dict = field(default_factory=dict)
    sensors: dict = field(default_factory=dict)
    output: str | None = None
    options: dict = field(default_factory=dict)
    source: str = "<config>"
    log_options: dict = field(default_factory=dict)

    def option_block(self, estimator: str | None = None) -> dict:
        """The option block of ``estimator`` (default: this run's estimator), ``{}`` if absent."""
        return dict(self.options.get(estimator or self.estimator, {}) or {})


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
)
ENCODER_KEYS = ("ticks_per_rev", "gear_ratio", "rollover", "columns")
INITIAL_KEYS = ("pose", "sigma")
LOG_KEYS = ("path", "topics", "joints")
INTEGRATORS = ("euler", "rk2", "exact")
#: Sensor-block keys that must be numbers (or, for sigma*, lists of numbers).
_SENSOR_NUMBER_KEY = re.compile(
    r"^(sigma.*|gate|var.*|min_.*|max_.*|.*_threshold|huber.*|"
    r"k|k_.*|offset.*|scale.*|bias.*|rate.*|delay|lever_arm)$"
)
_MOTION_NUMBER_KEY = re.compile(r"^(k|k_.*|var_floor.*|sigma.*|alpha.*|floor.*)$")


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _number(v, key: str, src: str, *, positive=False, nonneg=False, finite=True) -> float:
    if not _is_number(v):
        raise ConfigError(f"must be a number, got {type(v).__name__} {v!r}", src, key)
    v = float(v)
    if finite and not math.isfinite(v):
        raise ConfigError(f"must be finite, got {v!r}", src, key)
    if positive and not v > 0:
        raise ConfigError(f"must be positive, got {v!r}", src, key)
    if nonneg and not v >= 0:
        raise ConfigError(f"must not be negative, got {v!r}", src, key)
    return v


def _numbers(v, key: str, src: str, n: int | None = None, **kw) -> list[float]:
    if not isinstance(v, list | tuple):
        raise ConfigError(
            f"must be a list of {n or ''} numbers, got {v!r}".replace("  ", " "), src, key
        )
    if n is not None and len(v) != n:
        raise ConfigError(f"must have {n} elements, got {len(v)}", src, key)
    return [_number(x, f"{key}[{i}]", src, **kw) for i, x in enumerate(v)]


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


def _scalarish(v, key: str, src: str):
    """Open-block values: number, string, bool, None, or (nested) lists/mappings of those."""
    if v is None or isinstance(v, bool | str) or _is_number(v):
        if _is_number(v) and not math.isfinite(float(v)):
            raise ConfigError(f"must be finite, got {v!r}", src, key)
        return v
    if isinstance(v, list | tuple):
        return [_scalarish(x, f"{key}[{i}]", src) for i, x in enumerate(v)]
    if isinstance(v, dict):
        return {k: _scalarish(x, f"{key}.{k}", src) for k, x in _mapping(v, key, src).items()}
    raise ConfigError(f"unsupported value {v!r}", src, key)


def _resolve_log(v, src: str, base_dir: Path | None) -> tuple[str, dict]:
    opts: dict = {}
    if isinstance(v, dict):
        block = _mapping(v, "log", src)
        _unknown(block, LOG_KEYS, "log", src)
        if "path" not in block:
            raise ConfigError("missing required value", src, "log.path")
        path = _string(block["path"], "log.path", src)
        if "topics" in block:
            topics = _mapping(block["topics"], "log.topics", src)
            opts["topics"] = {
                k: [_string(x, f"log.topics.{k}[{i}]", src) for i, x in enumerate(t)]
                if isinstance(t, list)
                else _string(t, f"log.topics.{k}", src)
                for k, t in topics.items()
            }
        if "joints" in block:  # drive input name -> JointState joint name
            joints = _mapping(block["joints"], "log.joints", src)
            opts["joints"] = {k: _string(j, f"log.joints.{k}", src) for k, j in joints.items()}
    else:
        path = _string(v, "log", src)
    if path.startswith("builtin:"):
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
    # Geometry values are numbers (or lists of numbers/names for plug-in drives); the drive
    # class itself checks keys, presence and ranges in _check_drive.
    geometry = {
        k: _scalarish(val, f"robot.{k}", src)
        for k, val in robot.items()
        if k not in ("drive", "encoder")
    }
    for k, val in geometry.items():
        if isinstance(val, dict):
            raise ConfigError("a geometry value must be a number or a list", src, f"robot.{k}")
    out.update(geometry)
    if robot.get("encoder") is not None:
        enc = _mapping(robot["encoder"], "robot.encoder", src)
        _unknown(enc, ENCODER_KEYS, "robot.encoder", src)
        if "ticks_per_rev" not in enc:
            raise ConfigError("missing required value", src, "robot.encoder.ticks_per_rev")
        e = {
            "ticks_per_rev": _number(
                enc["ticks_per_rev"], "robot.encoder.ticks_per_rev", src, positive=True
            )
        }
        if "gear_ratio" in enc:
            e["gear_ratio"] = _number(
                enc["gear_ratio"], "robot.encoder.gear_ratio", src, positive=True
            )
        if enc.get("rollover") is not None:
            r = _number(enc["rollover"], "robot.encoder.rollover", src, positive=True)
            if r != int(r):
                raise ConfigError(f"must be an integer, got {r!r}", src, "robot.encoder.rollover")
            e["rollover"] = int(r)
        if "columns" in enc:
            cols = enc["columns"]
            if not isinstance(cols, list) or not all(isinstance(c, str) for c in cols):
                raise ConfigError("must be a list of column names", src, "robot.encoder.columns")
            e["columns"] = list(cols)
        out["encoder"] = e
    _check_drive(drive, geometry, src)
    return out


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


def _validate_motion(v, src: str) -> dict:
    motion = _mapping(v, "motion", src)
    out = {}
    for k, val in motion.items():
        key = f"motion.{k}"
        if k == "integrator":
            val = _string(val, key, src)
            if val not in INTEGRATORS:
                raise ConfigError(f"must be one of {', '.join(INTEGRATORS)}, got '{val}'", src, key)
        elif _MOTION_NUMBER_KEY.match(k):
            val = (
                _numbers(val, key, src, nonneg=True)
                if isinstance(val, list | tuple)
                else _number(val, key, src, nonneg=True)
            )
        else:
            val = _scalarish(val, key, src)
        out[k] = val
    return out


def _check_motion_against_drive(robot: dict, motion: dict, src: str) -> None:
    """``k_r``/``k_l`` need a left/right drive; a ``k`` list needs one entry per drive input."""
    from odofuse.drives import make_drive

    geometry = {k: v for k, v in robot.items() if k not in ("drive", "encoder")}
    names = tuple(make_drive(robot["drive"], **geometry).input_names)
    for key in ("k_r", "k_l"):
        if key in motion and names[:2] != ("left", "right"):
            raise ConfigError(
                f"applies to left/right wheels; drive '{robot['drive']}' has "
                f"inputs {', '.join(names)} (use k: [one per input])",
                src,
                f"motion.{key}",
            )
    for key in ("k", "var_floor"):
        if isinstance(motion.get(key), list) and len(motion[key]) != len(names):
            raise ConfigError(
                f"needs one number per drive input ({', '.join(names)}), got {len(motion[key])}",
                src,
                f"motion.{key}",
            )


def _validate_initial(v, src: str) -> dict:
    initial = _mapping(v, "initial", src)
    _unknown(initial, INITIAL_KEYS, "initial", src)
    out = {}
    # pose omitted: the estimators start from the log's own initial pose (builtin datasets,
    # pose graphs) or the origin.
    if "pose" in initial and initial["pose"] is not None:
        out["pose"] = _numbers(initial["pose"], "initial.pose", src, 3)
    if "sigma" in initial and initial["sigma"] is not None:
        out["sigma"] = _numbers(initial["sigma"], "initial.sigma", src, 3, nonneg=True)
    return out


def _validate_sensors(v, src: str) -> dict:
    sensors = _mapping(v, "sensors", src)
    out = {}
    for name, block in sensors.items():
        base = f"sensors.{name}"
        if block is True:
            block = {}
        b = _mapping(block, base, src)
        res = {}
        for k, val in b.items():
            key = f"{base}.{k}"
            if _SENSOR_NUMBER_KEY.match(k):
                if isinstance(val, list | tuple):
                    val = _numbers(val, key, src)
                else:
                    val = _number(val, key, src, positive=k.startswith("sigma"))
                if k == "gate" and not 0 < val < 1:
                    raise ConfigError(
                        f"a chi-square acceptance probability must be in (0, 1), got {val!r}",
                        src,
                        key,
                    )
                if k.startswith("sigma") and isinstance(val, list) and min(val) <= 0:
                    raise ConfigError("must be positive", src, key)
            else:
                val = _scalarish(val, key, src)
            res[k] = val
        out[name] = res
    return out


def _validate_options(v, src: str) -> dict:
    options = _mapping(v, "options", src)
    return {
        k: _scalarish(_mapping(b, f"options.{k}", src), f"options.{k}", src)
        for k, b in options.items()
    }


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
    base = Path(base_dir) if base_dir is not None else None
    log, log_options = _resolve_log(top["log"], src, base)
    estimator = (
        _string(top["estimator"], "estimator", src)
        if top.get("estimator") is not None
        else "dead_reckoning"
    )
    output = None
    if top.get("output") is not None:
        out = Path(_string(top["output"], "output", src)).expanduser()
        output = str(base / out if base is not None and not out.is_absolute() else out)
    if "description" in top and top["description"] is not None:
        _string(top["description"], "description", src)
    robot = _validate_robot(top["robot"], src)
    motion = _validate_motion(top.get("motion"), src)
    _check_motion_against_drive(robot, motion, src)
    return RunConfig(
        log=log,
        robot=robot,
        motion=motion,
        estimator=estimator,
        initial=_validate_initial(top.get("initial"), src),
        sensors=_validate_sensors(top.get("sensors"), src),
        output=output,
        options=_validate_options(top.get("options"), src),
        source=src,
        log_options=log_options,
    )


def _yaml_loader():
    """PyYAML's SafeLoader with YAML 1.2 floats: ``1e-4`` is a number, not the string "1e-4"."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

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
    text = path.read_text(encoding="utf-8")
    data = parse_yaml(text, str(path))
    if data is None:
        raise ConfigError("empty configuration file", str(path))
    if not isinstance(data, dict):
        raise ConfigError("the configuration must be a mapping of keys", str(path))
    return config_from_dict(data, str(path), path.parent)
