"""The built-in models by name (:data:`MODELS`) and :func:`measurement_models`, which builds a
run's models from its validated sensor blocks (built-in kinds and ``class:`` plug-ins)."""

from __future__ import annotations

import dataclasses

import numpy as np

from odofuse.declarations import LoopClosureOptions, PluginSensorOptions
from odofuse.errors import ConfigError
from odofuse.measurements.absolute import CompassHeading, GpsPosition
from odofuse.measurements.base import (
    MeasurementModel,
)
from odofuse.measurements.gyro import GyroYawRate
from odofuse.measurements.landmarks import BeaconRange, LandmarkBearing, LandmarkRangeBearing
from odofuse.options import explicit

#: Built-in model classes by name (the sensor block's ``model`` key).
MODELS: dict[str, type] = {
    "gps": GpsPosition,
    "gyro": GyroYawRate,
    "compass": CompassHeading,
    "range": BeaconRange,
    "bearing": LandmarkBearing,
    "range_bearing": LandmarkRangeBearing,
}

_LANDMARK_MODELS = ("range", "bearing", "range_bearing")
# Sensor options that are not fields of the model (read by the estimators, or aliases).
_NOT_MODEL_FIELDS = ("model", "robust", "gyrodometry", "threshold", "sigma_range", "optional")


def _accepts(cls, name: str) -> bool:
    """Whether ``cls(...)`` takes keyword ``name`` (or ``**kwargs``)."""
    import inspect

    try:
        params = inspect.signature(cls).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name == name or p.kind is p.VAR_KEYWORD for p in params)


def _build_plugin(stream: str, opts: PluginSensorOptions, landmarks, source: str):
    prefix, spec, cls = f"sensors.{stream}", opts.spec, opts.cls
    params = opts.params
    kwargs = dict(
        {f.name: getattr(params, f.name) for f in dataclasses.fields(params)}
        if dataclasses.is_dataclass(params)
        else params,
        name=stream,
    )
    if _accepts(cls, "landmarks"):
        kwargs["landmarks"] = landmarks
    try:
        model = cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"cannot build {spec}: {exc}", source, f"{prefix}.class") from None
    if hasattr(model, "gate") and dataclasses.is_dataclass(model):
        try:
            model = dataclasses.replace(model, gate=opts.gate)
        except (TypeError, ValueError):
            pass
    for attr in ("dim", "z", "h", "H", "R", "residual"):
        if not hasattr(model, attr):
            raise ConfigError(
                f"{spec} lacks '{attr}' of the MeasurementModel interface",
                source,
                f"{prefix}.class",
            )
    return model


def _build_one(stream: str, opts, landmarks, source: str):
    """The model of stream ``stream`` from its validated sensor options."""
    if isinstance(opts, PluginSensorOptions):
        return _build_plugin(stream, opts, landmarks, source)
    kind = opts.kind
    kwargs = {
        f.name: getattr(opts, f.name)
        for f in dataclasses.fields(opts)
        if f.name not in _NOT_MODEL_FIELDS
    }
    if getattr(opts, "sigma_range", None) is not None:
        kwargs["sigma"] = opts.sigma_range
    kwargs["name"] = stream
    if kind == "range_bearing" and {"sigma", "sigma_range", "sigma_bearing"} & explicit(opts):
        kwargs["file_noise"] = False  # the config's sigmas override the file's
    if kind in _LANDMARK_MODELS:
        if not landmarks:
            raise ConfigError(
                f"a '{kind}' sensor needs a map (map.csv) of landmark positions",
                source,
                f"sensors.{stream}",
            )
        kwargs["landmarks"] = {int(i): np.asarray(p, dtype=float) for i, p in landmarks.items()}
    return MODELS[kind](**kwargs)


def measurement_models(config, log=None) -> dict[str, MeasurementModel]:
    """Build the run's measurement models from ``config.sensors``.

    Parameters
    ----------
    config : RunConfig
        ``sensors`` maps a stream name to its validated options
        (:data:`odofuse.declarations.SENSOR_OPTIONS`, one class per model kind, chosen by the
        block's ``model`` or the stream name, :data:`STREAM_DEFAULTS`; or a
        ``class: "package.module:Class"`` plug-in). Keys used by the estimators
        (``gyrodometry``, ``threshold``, ``robust``) are not passed to the models.
    log : SensorLog, optional
        Supplies the landmark map, and the first fix of a lat/lon GPS stream as its datum
        when the sensor block sets none.

    Returns
    -------
    dict
        Stream name -> model, in the config's order; streams absent from ``log`` are kept
        (the estimator skips them).

    Raises
    ------
    ConfigError
        Naming ``sensors.<stream>.<key>`` and ``config.source``.
    """
    source = getattr(config, "source", "<config>")
    landmarks = dict(getattr(log, "landmarks", {}) or {})
    models = {
        s: _build_one(s, b, landmarks, source)
        for s, b in config.sensors.items()
        if not isinstance(b, LoopClosureOptions)  # read by the graph estimators, not a model
    }
    # A lat/lon GPS stream without a datum is expressed about its first fix (the usual default
    # of robot_localization's navsat_transform when no datum is set).
    streams = getattr(log, "streams", {}) or {}
    for name, model in models.items():
        stream = streams.get(name)
        if (
            isinstance(model, GpsPosition)
            and model.datum is None
            and stream is not None
            and len(stream)
            and {"lat", "lon"} <= set(stream.columns)
        ):
            models[name] = dataclasses.replace(
                model, datum=(float(stream["lat"][0]), float(stream["lon"][0]))
            )
    return models
