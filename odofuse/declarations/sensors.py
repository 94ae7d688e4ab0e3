"""Declarations of the sensor blocks: one options class per measurement-model kind.

Owns :data:`SENSOR_OPTIONS` (model kind -> options class), :data:`GRAPH_STREAM_OPTIONS`
(``sensors.loop_closures``), :data:`STREAM_DEFAULTS` (stream name -> default model kind),
:class:`PluginSensorOptions` (a user model ``class: package.module:Class``) and
:func:`sensor_options`, which validates one ``sensors.<stream>`` block.
"""

from __future__ import annotations

import types
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from odofuse.declarations.common import _NONNEG, _POSITIVE, gate_probability, robust_loss
from odofuse.errors import ConfigError
from odofuse.options import from_mapping, option


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
    optional: bool = option(
        False,
        unit="-",
        doc="a log without this stream is a warning (degraded when no other absolute sensor "
        "is left), not an error",
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
    calibrate: bool = option(
        True,
        unit="-",
        doc="estimate the gyro bias (every MEMS gyro has one); false: the bias is known to be 0",
    )
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
#: Absolute sensor kinds (they observe the pose against the world, not its change) and the
#: dimension of one reading: the graph's default gate loss (:meth:`GraphOptions.for_run`) and
#: the default odometry calibration (``odometry_calibration: auto``) read it.
ABSOLUTE_KINDS: dict[str, int] = {
    "gps": 2,
    "compass": 1,
    "range": 1,
    "bearing": 1,
    "range_bearing": 2,
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


def absolute_streams(sensors: Mapping) -> dict[str, int]:
    """Stream -> reading dimension of the absolute sensors among validated sensor blocks."""
    return {
        s: ABSOLUTE_KINDS[b.kind]
        for s, b in sensors.items()
        if getattr(b, "kind", None) in ABSOLUTE_KINDS and not isinstance(b, type)
    }


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
