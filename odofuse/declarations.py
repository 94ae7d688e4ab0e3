"""Built-in option declarations: one frozen dataclass per config block, sensor kind, estimator.

Every key a run config may carry outside ``robot``'s drive geometry is declared here once, with
its type, unit, default and meaning (:func:`odofuse.options.option`); :mod:`odofuse.config`
validates the YAML blocks into these classes, the estimators and models read the instances, and
the docs tables and ``odofuse options`` are generated from them. The registries:

- :data:`BLOCK_OPTIONS`: ``motion``, ``initial``, ``robot.encoder``, ``log``;
- :data:`SENSOR_OPTIONS`: measurement-model kind (a sensor block's ``model``, by default
  :data:`STREAM_DEFAULTS` of its stream name) -> options class;
- :data:`ESTIMATOR_OPTIONS`: estimator name -> options class.

A user estimator ``package.module:function`` or measurement model ``class: package.module:Class``
declares its own options the same way, as an attribute ``Options`` (a frozen dataclass of
:func:`~odofuse.options.option` fields) on the function or class.
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from odofuse.errors import ConfigError
from odofuse.io.csvlog import REPAIR_DUPLICATES
from odofuse.options import coerce, from_mapping, markdown_table, option, render_docs

INTEGRATORS = ("euler", "rk2", "exact", "euler_end")
ROBUST_KINDS = ("none", "huber", "cauchy", "tukey")
#: Default thresholds ``k`` (in sigma) of the robust losses: 95 % efficiency on Gaussian noise.
ROBUST_DEFAULT_K = {"huber": 1.345, "cauchy": 2.3849, "tukey": 4.6851}
DEFAULT_INITIAL_SIGMA = (0.1, 0.1, 0.05)
DEFAULT_LATE_WINDOW = 0.5  # s


# ------------------------------------------------------------------------------ parse hooks
def robust_loss(value, key: str, source: str) -> tuple[str, float]:
    """A robust loss ``huber | cauchy | tukey | none`` or ``{type, k}`` as ``(kind, k)``."""
    if isinstance(value, str) or value is None:
        kind, k = ("none" if value is None else value), None
    elif isinstance(value, Mapping):
        unknown = set(value) - {"type", "k"}
        if unknown:
            raise ConfigError(
                f"unknown key(s) {', '.join(sorted(unknown))}; use type and k",
                file=source,
                key=f"{key}.{sorted(unknown)[0]}",
            )
        kind, k = value.get("type", "huber"), value.get("k")
    else:
        raise ConfigError(
            f"expected a loss name or {{type, k}}, got {value!r}", file=source, key=key
        )
    if kind not in ROBUST_KINDS:
        raise ConfigError(
            f"unknown robust loss {kind!r}; use one of {', '.join(ROBUST_KINDS)}",
            file=source,
            key=key,
        )
    if kind == "none":
        return ("none", 0.0)
    if k is None:
        return (kind, ROBUST_DEFAULT_K[kind])
    if isinstance(k, bool) or not isinstance(k, int | float) or not math.isfinite(k):
        raise ConfigError(f"expected a number, got {k!r}", file=source, key=f"{key}.k")
    if not k > 0:
        raise ConfigError("robust threshold k must be positive", file=source, key=f"{key}.k")
    return (kind, float(k))


def gate_probability(value, key: str, source: str) -> float | None:
    """A chi-square acceptance probability in (0, 1); ``null`` or ``false`` disables the gate."""
    if value is None or value is False:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 < value < 1.0:
        raise ConfigError(
            f"a chi-square acceptance probability must be in (0, 1), got {value!r}", source, key
        )
    return float(value)


_POSITIVE = {"minimum": 0, "exclusive_minimum": True}
_NONNEG = {"minimum": 0}


# ------------------------------------------------------------------------------- blocks
@dataclass(frozen=True)
class MotionOptions:
    """``motion``: the odometry error model (Siegwart & Nourbakhsh) and the integrator."""

    integrator: str = option(
        "exact", unit="-", doc="pose integration of one step", choices=INTEGRATORS
    )
    k: float | tuple[float, ...] = option(
        1.0e-4,
        unit="input^2 per input",
        doc="variance per unit of each drive input's travel (one number, or one per input)",
        **_NONNEG,
    )
    k_r: float | None = option(
        None, unit="rad", doc="right wheel's k (left/right drives); overrides k", **_NONNEG
    )
    k_l: float | None = option(
        None, unit="rad", doc="left wheel's k (left/right drives); overrides k", **_NONNEG
    )
    var_floor: float | tuple[float, ...] = option(
        0.0,
        unit="input^2",
        doc="variance added to each input every step (one number, or one per input)",
        **_NONNEG,
    )
    k_theta_ds: float | None = option(
        None,
        unit="rad^2 per m",
        doc=(
            "heading-input variance per metre travelled (increments, twist); null: k[1]^2/k[0], "
            "the two-wheel robot with the same k (docs/motion.md)"
        ),
        **_NONNEG,
    )
    var_rate: float | tuple[float, ...] = option(
        0.0,
        unit="input^2 per s",
        doc="variance added to each input per second (filters; one number, or one per input)",
        **_NONNEG,
    )
    steer_sigma: float = option(0.01, unit="rad", doc="noise of a steering-angle input", **_NONNEG)
    alphas: tuple[float, float, float, float] | None = option(
        None,
        unit="-",
        doc="Thrun's velocity-model a1..a4 on variances (twist and increments drives)",
        **_NONNEG,
    )


@dataclass(frozen=True)
class InitialOptions:
    """``initial``: the prior on the start pose."""

    pose: tuple[float, float, float] | None = option(
        None, unit="m, m, rad", doc="start pose; null: the log's own start pose, else the origin"
    )
    sigma: tuple[float, float, float] = option(
        DEFAULT_INITIAL_SIGMA,
        unit="m, m, rad",
        doc="standard deviations of the start pose",
        **_NONNEG,
    )


@dataclass(frozen=True)
class EncoderOptions:
    """``robot.encoder``: wheel angles in ``wheels.csv`` are encoder ticks."""

    ticks_per_rev: float = option(
        unit="ticks", doc="ticks per revolution of the encoder shaft", **_POSITIVE
    )
    gear_ratio: float = option(
        1.0, unit="-", doc="encoder revolutions per wheel revolution", **_POSITIVE
    )
    rollover: int | None = option(
        None, unit="ticks", doc="counter period (unwrapped); null: none", **_POSITIVE
    )
    columns: tuple[str, ...] | None = option(
        None, unit="-", doc="the tick columns; null: the drive's wheel inputs"
    )


@dataclass(frozen=True)
class RepairOptions:
    """``log.repair``: how a CSV folder's out-of-order and duplicated rows are repaired."""

    sort: bool = option(False, unit="-", doc="sort rows by t (moved rows counted)")
    duplicates: str = option(
        "drop_exact",
        unit="-",
        doc="rows with a repeated t: error, drop exact copies, keep the first, drop conflicting",
        choices=REPAIR_DUPLICATES,
    )


@dataclass(frozen=True)
class LogOptions:
    """``log`` as a mapping (a bag with its topics)."""

    path: str = option(unit="-", doc="log folder, bag or builtin:NAME (relative to the config)")
    topics: dict[str, str | tuple[str, ...]] | None = option(
        None, unit="-", doc="stream kind -> topic name (or list of topics) of a bag"
    )
    joints: dict[str, str] | None = option(
        None, unit="-", doc="drive input name -> JointState joint name of a bag"
    )
    repair: RepairOptions | None = option(
        None, unit="-", doc="CSV folders: opt-in repair policy for time order and duplicates"
    )
    wheel_inputs: str = option(
        "position",
        unit="-",
        doc="wheels.csv / JointState holds positions, or wheel speeds integrated per row",
        choices=("position", "velocity"),
    )


# ------------------------------------------------------------------------------- sensors
@dataclass(frozen=True)
class SensorOptions:
    """Keys of every built-in sensor block; each kind adds its own (``kind`` names the model)."""

    kind: ClassVar[str] = ""
    model: str | None = option(
        None, unit="-", doc="measurement model (default by stream name)", type_name="string"
    )
    sigma: float = option(1.0, unit="-", doc="measurement noise", **_POSITIVE)
    gate: float | None = option(
        0.999,
        unit="-",
        doc="chi-square acceptance probability of the innovation gate; null: none",
        parse=gate_probability,
        type_name="float in (0, 1) or null",
    )
    robust: tuple[str, float] | None = option(
        None,
        unit="sigma",
        doc="graph estimators: robust loss of this stream",
        parse=robust_loss,
        type_name="huber \\| cauchy \\| tukey \\| none or {type, k}",
    )


@dataclass(frozen=True)
class GpsOptions(SensorOptions):
    """``sensors.gps``: position fixes (local metres or WGS-84 lat/lon)."""

    kind: ClassVar[str] = "gps"
    sigma: float = option(1.0, unit="m", doc="position noise per axis", **_POSITIVE)
    lever_arm: tuple[float, float] = option(
        (0.0, 0.0), unit="m", doc="antenna position in the robot frame"
    )
    datum: tuple[float, ...] | None = option(
        None,
        unit="deg, deg[, m]",
        doc="ENU origin lat, lon[, alt] of lat/lon fixes; null: the first fix",
    )

    def check(self) -> None:
        if self.datum is not None and len(self.datum) not in (2, 3):
            raise ConfigError(
                f"expected 2 or 3 finite numbers, got {list(self.datum)!r}", key="datum"
            )


@dataclass(frozen=True)
class GyroOptions(SensorOptions):
    """``sensors.gyro``: yaw rate, as a measurement or (gyrodometry) in the prediction."""

    kind: ClassVar[str] = "gyro"
    sigma: float = option(1.0, unit="rad/s", doc="yaw-rate noise", **_POSITIVE)
    calibrate: bool = option(False, unit="-", doc="estimate the gyro bias online")
    bias_sigma: float = option(0.01, unit="rad/s", doc="prior sigma of the bias", **_POSITIVE)
    bias_walk: float = option(0.0, unit="rad/s/sqrt(s)", doc="random walk of the bias", **_NONNEG)
    gyrodometry: bool = option(
        False,
        unit="-",
        doc="filters: use the gyro's heading change when it disagrees with odometry",
    )
    threshold: float | None = option(
        None,
        unit="rad",
        doc="gyrodometry: disagreement per odometry step that switches to the gyro",
        **_NONNEG,
    )


@dataclass(frozen=True)
class CompassOptions(SensorOptions):
    """``sensors.compass``: absolute heading."""

    kind: ClassVar[str] = "compass"
    sigma: float = option(1.0, unit="rad", doc="heading noise", **_POSITIVE)
    calibrate: bool = option(False, unit="-", doc="estimate a heading offset online")
    offset_sigma: float = option(0.1, unit="rad", doc="prior sigma of the offset", **_POSITIVE)


@dataclass(frozen=True)
class RangeOptions(SensorOptions):
    """``sensors.ranges``: range to a known beacon (``map.csv``)."""

    kind: ClassVar[str] = "range"
    sigma: float = option(1.0, unit="m", doc="range noise", **_POSITIVE)
    calibrate: bool = option(
        False, unit="-", doc="estimate range = scale * distance + offset online"
    )
    scale_sigma: float = option(
        0.05, unit="-", doc="prior sigma of the scale (nominal 1)", **_POSITIVE
    )
    offset_sigma: float = option(
        0.5, unit="m", doc="prior sigma of the offset (nominal 0)", **_POSITIVE
    )
    scale_walk: float = option(0.0, unit="1/sqrt(s)", doc="random walk of the scale", **_NONNEG)
    offset_walk: float = option(0.0, unit="m/sqrt(s)", doc="random walk of the offset", **_NONNEG)


@dataclass(frozen=True)
class BearingOptions(SensorOptions):
    """``sensors.bearings``: robot-frame bearing to a mapped landmark."""

    kind: ClassVar[str] = "bearing"
    sigma: float = option(1.0, unit="rad", doc="bearing noise", **_POSITIVE)


@dataclass(frozen=True)
class RangeBearingOptions(SensorOptions):
    """``sensors.landmarks``: robot-frame range and bearing to a mapped landmark."""

    kind: ClassVar[str] = "range_bearing"
    sigma: float = option(1.0, unit="m", doc="range noise", **_POSITIVE)
    sigma_range: float | None = option(
        None, unit="m", doc="range noise (same as sigma; wins when both are set)", **_POSITIVE
    )
    sigma_bearing: float = option(0.02, unit="rad", doc="bearing noise", **_POSITIVE)


#: Model kind -> options class (the ``model`` key of a sensor block).
@dataclass(frozen=True)
class LoopClosureOptions:
    """``sensors.loop_closures``: the pose graph's loop closures (graph estimators only)."""

    kind: ClassVar[str] = "loop_closures"
    sigma: float | tuple[float, float, float] | None = option(
        None,
        unit="m, m, rad",
        doc="replaces the file's covariance by diag(sigma^2); null: the file's own noise",
        **_POSITIVE,
    )
    robust: tuple[str, float] | None = option(
        None,
        unit="sigma",
        doc="robust loss of the loop closures",
        parse=robust_loss,
        type_name="huber \\| cauchy \\| tukey \\| none or {type, k}",
    )


SENSOR_OPTIONS: dict[str, type] = {
    c.kind: c
    for c in (
        GpsOptions,
        GyroOptions,
        CompassOptions,
        RangeOptions,
        BearingOptions,
        RangeBearingOptions,
    )
}
#: Sensor blocks that configure the graph estimators' use of a stream, not a measurement model.
GRAPH_STREAM_OPTIONS: dict[str, type] = {"loop_closures": LoopClosureOptions}

#: The model a stream gets when its block names neither ``model`` nor ``class``.
STREAM_DEFAULTS: dict[str, str] = {
    "gps": "gps",
    "gyro": "gyro",
    "compass": "compass",
    "ranges": "range",
    "bearings": "bearing",
    "landmarks": "range_bearing",
}


@dataclass(frozen=True)
class PluginSensorOptions:
    """A user model ``class: package.module:Class``.

    ``gate``/``robust`` as for every sensor; ``params`` is the class's own ``Options``
    instance, or (a class without ``Options``) its other keys, unchecked.
    """

    spec: str
    cls: type
    params: object
    gate: float | None = 0.999
    robust: tuple[str, float] | None = None


def stream_kind(stream: str) -> str | None:
    """The default model kind of a stream name; ``gyro_2`` (a second IMU) is a ``gyro``."""
    if stream in STREAM_DEFAULTS:
        return STREAM_DEFAULTS[stream]
    base, _, number = stream.rpartition("_")
    return STREAM_DEFAULTS.get(base) if number.isdigit() else None


def sensor_options(stream: str, block, source: str = "<config>"):
    """Validate the block ``sensors.<stream>`` into its kind's options (or a plug-in's)."""
    prefix = f"sensors.{stream}"
    if block is True or block is None:
        block = {}
    if not isinstance(block, Mapping):
        raise ConfigError(f"expected a mapping, got {block!r}", source, prefix)
    block = dict(block)
    if "class" in block:
        return _plugin_sensor(stream, block, source)
    if stream in GRAPH_STREAM_OPTIONS:
        return from_mapping(GRAPH_STREAM_OPTIONS[stream], block, prefix, source)
    kind = block.get("model", stream_kind(stream))
    if kind not in SENSOR_OPTIONS:
        raise ConfigError(
            f"no measurement model for stream '{stream}'; set 'model' to one of "
            f"{', '.join(SENSOR_OPTIONS)} or 'class' to 'package.module:Class'",
            source,
            f"{prefix}.model",
        )
    return from_mapping(SENSOR_OPTIONS[kind], {**block, "model": kind}, prefix, source)


def _plugin_sensor(stream: str, block: dict, source: str) -> PluginSensorOptions:
    from odofuse.plugins import SENSOR_METHODS, load_class

    prefix = f"sensors.{stream}"
    spec = block.pop("class")
    try:
        cls = load_class(str(spec), f"measurement model of {prefix}", SENSOR_METHODS)
    except ConfigError as exc:
        raise ConfigError(str(exc), source, f"{prefix}.class") from None
    gate = gate_probability(block.pop("gate", 0.999), f"{prefix}.gate", source)
    robust = block.pop("robust", None)
    robust = None if robust is None else robust_loss(robust, f"{prefix}.robust", source)
    own = getattr(cls, "Options", None)
    params = from_mapping(own, block, prefix, source) if own else types.MappingProxyType(block)
    return PluginSensorOptions(str(spec), cls, params, gate, robust)


# ---------------------------------------------------------------------------- estimators
@dataclass(frozen=True)
class DeadReckoningOptions:
    """``options.dead_reckoning``: the gyro-vs-wheels heading check (when a gyro is logged)."""

    heading_window: float = option(
        1.0,
        unit="s",
        doc="window over which gyro and wheel heading changes are compared",
        **_POSITIVE,
    )
    heading_alpha: float = option(
        1e-3,
        unit="-",
        doc="false-alarm probability of the disagreement test over the run",
        **_POSITIVE,
    )
    bias_sigma: float = option(
        0.01, unit="rad/s", doc="prior sigma of an unmodelled gyro bias in that test", **_NONNEG
    )


@dataclass(frozen=True)
class FilterOptions:
    """Keys of every recursive filter."""

    late_window: float = option(
        DEFAULT_LATE_WINDOW,
        unit="s",
        doc="measurements up to this late are replayed, older dropped",
        **_NONNEG,
    )
    odometry_calibration: bool = option(
        False,
        unit="-",
        doc=(
            "estimate the odometry's systematic errors online (increments: ds_scale, "
            "dtheta_scale, dtheta_bias; differential, skid_steer: wheel_radius_ratio, "
            "track_width_scale)"
        ),
    )
    odometry_calibration_sigma: tuple[float, ...] | None = option(
        None,
        unit="-, -, rad/s",
        doc="prior sigmas of those states; null: the graph's defaults (docs/filters.md)",
        **_POSITIVE,
    )
    odometry_calibration_walk: tuple[float, ...] | None = option(
        None,
        unit="per sqrt(s)",
        doc="random-walk sigmas of those states; null: 1e-4 (scales), 1e-5 rad/s (bias)",
        **_NONNEG,
    )
    nis_window: int = option(
        20,
        unit="readings",
        doc="sliding window of one sensor's readings for the NIS band check",
        minimum=2,
    )
    nis_alpha: float = option(
        1e-3,
        unit="-",
        doc="false-alarm probability of the NIS band over the run (Bonferroni)",
        **_POSITIVE,
    )
    reject_run: int = option(
        5,
        unit="readings",
        doc="consecutive rejections of one stream that mean divergence",
        minimum=1,
    )
    recovery: bool = option(
        True, unit="-", doc="re-open (inflate the pose covariance) when a stream shows divergence"
    )
    max_inflation: float = option(
        1e6, unit="-", doc="largest pose covariance inflation of one recovery", minimum=1
    )
    max_condition: float = option(
        1e10, unit="-", doc="largest condition number of the pose correlation matrix", minimum=1
    )
    growth_factor: float = option(
        100.0,
        unit="-",
        doc="growth of the position sigma over its running minimum reported",
        minimum=1,
    )
    calib_sigmas: float = option(
        5.0,
        unit="sigma",
        doc="distance from its prior of a calibration at its bound",
        **_POSITIVE,
    )
    slip: bool = option(
        True, unit="-", doc="robust odometry: widen a step's input noise when the gyro disagrees"
    )
    slip_gate: float = option(
        0.999,
        unit="-",
        doc="chi-square probability of the per-step gyro-wheel disagreement",
        minimum=0,
        maximum=1,
        exclusive_minimum=True,
        exclusive_maximum=True,
    )


@dataclass(frozen=True)
class EkfOptions(FilterOptions):
    """``options.ekf``: the extended Kalman filter."""


@dataclass(frozen=True)
class UkfOptions(FilterOptions):
    """``options.ukf``: the unscented Kalman filter (Van der Merwe sigma points)."""

    alpha: float = option(0.5, unit="-", doc="spread of the sigma points", **_POSITIVE)
    beta: float = option(2.0, unit="-", doc="prior knowledge of the distribution (2: Gaussian)")
    kappa: float = option(0.0, unit="-", doc="secondary scaling")


@dataclass(frozen=True)
class ParticleOptions(FilterOptions):
    """``options.particle``: the particle filter."""

    particles: int = option(1000, unit="-", doc="number of particles", minimum=1)
    seed: int = option(0, unit="-", doc="seed of the filter's random generator", **_NONNEG)
    resample_threshold: float = option(
        0.5,
        unit="-",
        doc="resample when the effective sample size falls below this fraction",
        minimum=0,
        maximum=1,
    )
    roughening: float = option(
        0.1,
        unit="-",
        doc="Liu-West kernel width h of the calibration states",
        minimum=0,
        maximum=1,
        exclusive_maximum=True,
    )
    regularise: bool = option(
        True, unit="-", doc="regularised resampling: kernel jitter of the pose after resampling"
    )
    bandwidth_scale: float = option(
        1.0,
        unit="-",
        doc="multiplier of Silverman's kernel bandwidth for the pose jitter",
        **_NONNEG,
    )


@dataclass(frozen=True)
class UncheckedOptions:
    """An estimator block whose keys the estimator itself validates (the graph estimators until
    their ``GraphOptions`` move to :func:`~odofuse.options.option` fields, and user estimators
    without ``Options``); ``values`` is the block, read-only."""

    values: Mapping = dataclasses.field(default_factory=lambda: types.MappingProxyType({}))

    @classmethod
    def from_block(cls, mapping, key_prefix: str, source: str) -> UncheckedOptions:
        if mapping is None:
            mapping = {}
        if not isinstance(mapping, Mapping):
            raise ConfigError(
                f"must be a mapping, got {type(mapping).__name__} {mapping!r}", source, key_prefix
            )
        return cls(types.MappingProxyType(dict(mapping)))


#: Estimator name -> options class (``options.<name>``).
ESTIMATOR_OPTIONS: dict[str, type] = {
    "dead_reckoning": DeadReckoningOptions,
    "ekf": EkfOptions,
    "ukf": UkfOptions,
    "particle": ParticleOptions,
    "smoother": UncheckedOptions,
    "isam2": UncheckedOptions,
    "fixed_lag": UncheckedOptions,
}


@dataclass(frozen=True)
class OutputOptions:
    """``options.output``: the ROS 2 replay file ``trajectory.mcap`` of a run."""

    mcap: bool | None = option(
        None, unit="-", doc="write trajectory.mcap; null: when the log is a ROS 2 bag"
    )
    topic: str = option("/odometry/filtered", unit="-", doc="topic of the nav_msgs/Odometry")
    map_frame: str = option("map", unit="-", doc="REP-105 map frame id")
    odom_frame: str | None = option(
        None, unit="-", doc="REP-105 odom frame id; null: the bag's Odometry frame, else odom"
    )
    base_frame: str | None = option(
        None, unit="-", doc="robot frame id; null: the bag's child_frame_id, else base_link"
    )


#: ``options.<name>`` blocks that configure the run rather than an estimator.
RUN_OPTIONS: dict[str, type] = {"output": OutputOptions}

#: Config block -> options class.
BLOCK_OPTIONS: dict[str, type] = {
    "motion": MotionOptions,
    "initial": InitialOptions,
    "robot.encoder": EncoderOptions,
    "log": LogOptions,
}


def estimator_options_class(name: str, source: str = "<config>") -> type:
    """The options class of estimator ``name``: registered, or a user function's ``Options``."""
    if name in ESTIMATOR_OPTIONS:
        return ESTIMATOR_OPTIONS[name]
    if name in RUN_OPTIONS:
        return RUN_OPTIONS[name]
    if ":" not in name:
        raise ConfigError(
            f"unknown estimator '{name}'; known: {', '.join(ESTIMATOR_OPTIONS)}",
            source,
            f"options.{name}",
        )
    from odofuse.plugins import load_function

    try:
        run = load_function(name, "estimator")
    except ConfigError as exc:
        raise ConfigError(str(exc), source, f"options.{name}") from None
    return getattr(run, "Options", UncheckedOptions)


def estimator_options(name: str, block=None, source: str = "<config>"):
    """``options.<name>`` validated into its class (``block`` may already be an instance)."""
    return coerce(estimator_options_class(name, source), block, f"options.{name}", source)


# ---------------------------------------------------------------------------------- docs
#: The docs files whose ``<!-- options:NAME -->`` tables are generated.
DOC_FILES = ("docs/filters.md", "docs/formats.md")


def catalogue() -> dict[str, tuple[type, str]]:
    """Every declared block: name -> (class, dotted key prefix), for the docs and the CLI."""
    out = {name: (cls, name) for name, cls in BLOCK_OPTIONS.items()}
    for kind, cls in SENSOR_OPTIONS.items():
        out[f"sensors.{kind}"] = (cls, "sensors.<stream>")
    for stream, cls in GRAPH_STREAM_OPTIONS.items():
        out[f"sensors.{stream}"] = (cls, f"sensors.{stream}")
    for name, cls in ESTIMATOR_OPTIONS.items():
        if cls is not UncheckedOptions and dataclasses.fields(cls):
            out[name] = (cls, f"options.{name}")
    for name, cls in RUN_OPTIONS.items():
        out[name] = (cls, f"options.{name}")
    return out


def doc_tables() -> dict[str, str]:
    """Marker name -> generated markdown table."""
    return {name: markdown_table(cls, prefix) for name, (cls, prefix) in catalogue().items()}


def main(argv: list[str] | None = None) -> int:
    """``python -m odofuse.declarations --write-docs [--check]``: regenerate docs tables."""
    import argparse
    from pathlib import Path

    p = argparse.ArgumentParser(prog="python -m odofuse.declarations")
    p.add_argument("--write-docs", action="store_true", help="rewrite the tables in docs/*.md")
    p.add_argument("--check", action="store_true", help="exit 1 if a docs table is out of date")
    args = p.parse_args(argv)
    root = Path(__file__).resolve().parent.parent
    stale = []
    for rel in DOC_FILES:
        path = root / rel
        text = path.read_text(encoding="utf-8")
        new = render_docs(text, doc_tables())
        if new != text:
            stale.append(rel)
            if args.write_docs:
                path.write_text(new, encoding="utf-8")
    for rel in stale:
        print(f"{'rewrote' if args.write_docs else 'out of date'}: {rel}")
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    raise SystemExit(main())
