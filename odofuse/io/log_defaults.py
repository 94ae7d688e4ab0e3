"""What a log supplies when the config is silent: message noise, sensor mounts, GPS datum.

:func:`apply_log_defaults` runs between loading a log and running an estimator (``odofuse
run`` calls it). It owns the precedence rule "the config overrides, the log fills in":

* message covariances (``SensorLog.ros["message_noise"]``, from a bag) are per-row noise
  columns; a ``sigma`` in the stream's sensor block overrides them (the columns are dropped);
* the ``increments`` drive takes ``var_floor`` (per-step variances of ``ds`` and ``dtheta``)
  from the Odometry covariances, their median over the log, when the ``motion`` block sets
  none of ``k``, ``k_l``, ``k_r``, ``var_floor``;
* a GPS sensor block without ``lever_arm`` takes it from ``/tf_static`` (the GPS frame's
  ``x, y`` in the base frame);
* a sensor block for the k-th topic of a kind (``gyro_2``, ``compass_2``, ``gps_2``) without
  ``model`` or ``class`` gets the model of its kind;
* a GPS stream in ``lat, lon`` without ``datum`` is expressed about its first fix, and the log
  counts the repair ``<stream>.datum_first_fix`` so that ``metrics.json`` shows it (the first
  fix is noisy: give ``datum`` for repeatable results).

Everything applied is listed in the returned log's ``ros["defaults"]``.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from odofuse.io.log import SensorLog, Stream

_KIND_MODELS = {"gyro": "gyro", "compass": "compass", "gps": "gps"}


def _kind(stream: str) -> str:
    m = re.fullmatch(r"(.+)_(\d+)", stream)
    return m.group(1) if m else stream


def _drop_columns(stream: Stream, cols) -> Stream:
    keep = [i for i, c in enumerate(stream.columns) if c not in cols]
    return Stream(
        stream.name,
        stream.source,
        stream.t,
        tuple(stream.columns[i] for i in keep),
        stream.values[:, keep],
    )


def apply_log_defaults(config, log: SensorLog):
    """The config and log an estimator runs on, with the log's defaults filled in.

    Parameters
    ----------
    config : RunConfig
    log : SensorLog

    Returns
    -------
    config : RunConfig
        With ``sensors`` / ``motion`` defaults from the log (never overriding a config key).
    log : SensorLog
        Message noise columns dropped where the config gives ``sigma``; repairs and
        ``ros["defaults"]`` (``{"sensors.gps.lever_arm": [x, y], ...}``) updated.
    """
    ros = dict(log.ros or {})
    noise = dict(ros.get("message_noise", {}))
    mounts = ros.get("mounts", {})
    sensors = {k: dict(v or {}) for k, v in (config.sensors or {}).items()}
    motion = dict(config.motion or {})
    streams = dict(log.streams)
    repairs = dict(log.repairs)
    applied: dict = {}
    for name, block in sensors.items():
        kind = _kind(name)
        if name != kind and kind in _KIND_MODELS and "model" not in block and "class" not in block:
            block["model"] = _KIND_MODELS[kind]
            applied[f"sensors.{name}.model"] = block["model"]
        if "sigma" in block and name in noise and name in streams:
            streams[name] = _drop_columns(streams[name], noise.pop(name))
        is_gps = block.get("model", kind) == "gps" and "class" not in block
        if not is_gps:
            continue
        if "lever_arm" not in block and name in mounts:
            block["lever_arm"] = [float(mounts[name][0]), float(mounts[name][1])]
            applied[f"sensors.{name}.lever_arm"] = block["lever_arm"]
        s = streams.get(name)
        if "datum" not in block and s is not None and len(s) and {"lat", "lon"} <= set(s.columns):
            block["datum"] = [float(s["lat"][0]), float(s["lon"][0])]
            applied[f"sensors.{name}.datum"] = block["datum"]
            repairs[f"{name}.datum_first_fix"] = 1
    odo = streams.get("odometry")
    if (
        config.robot.get("drive") == "increments"
        and odo is not None
        and {"var_ds", "var_dtheta"} <= set(odo.columns)
        and not {"k", "k_l", "k_r", "var_floor"} & set(motion)
    ):
        floor = [float(np.median(odo["var_ds"])), float(np.median(odo["var_dtheta"]))]
        motion.update(k=[0.0, 0.0], var_floor=floor)
        applied["motion.var_floor"] = floor
    ros["message_noise"] = noise
    ros["defaults"] = applied
    config = dataclasses.replace(config, sensors=sensors, motion=motion)
    log = dataclasses.replace(log, streams=streams, repairs=repairs, ros=ros)
    return config, log
