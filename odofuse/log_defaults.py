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
* a GPS sensor block of a bag (a log with ``ros`` metadata) without ``robust`` takes Huber
  (:data:`~odofuse.declarations.common.ROBUST_DEFAULT_K`) for the graph estimators, when its
  ``gate`` is on: the filters reject a fix beyond the gate, and without a robust loss the graph
  has no such rejection, so a multipath outlier pulls the whole (rigid) trajectory. NavSatFix
  fixes come with the receiver's own covariance, and receivers report multipath jumps of tens
  of metres with it (the simulated bag's two 25 m outliers moved iSAM2's estimate 0.3 m);
* a GPS stream in ``lat, lon`` without ``datum`` is expressed about its first fix, and the log
  counts the repair ``<stream>.datum_first_fix`` so that ``metrics.json`` shows it (the first
  fix is noisy: give ``datum`` for repeatable results).

Everything applied is listed in the returned log's ``ros["defaults"]``. Applying it again to
its own result changes nothing (a bag is a log whose ``ros`` holds more than this function's
own two keys: until session 32 a CSV log with a GPS, once through, looked like a bag and a
second pass gave its GPS Huber's loss, which ``benchmarks/bench_status.py``'s second opinion
did). (The k-th topic of a
kind, ``gyro_2``, takes its kind's model by name: :func:`odofuse.declarations.stream_kind`.)
"""

from __future__ import annotations

import dataclasses

import numpy as np

from odofuse.declarations import GpsOptions
from odofuse.declarations.common import ROBUST_DEFAULT_K
from odofuse.io.log import SensorLog, Stream
from odofuse.options import explicit


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
        With ``sensors`` / ``motion`` values from the log where the config gave none
        (:func:`odofuse.options.explicit`): a GPS lever arm from ``/tf_static``, a bag GPS's
        robust loss, a datum from the first fix, an increments error model from the Odometry
        covariances.
    log : SensorLog
        Message noise columns dropped where the config gives ``sigma``; repairs and
        ``ros["defaults"]`` (``{"sensors.gps.lever_arm": [x, y], ...}``) updated.
    """
    ros = dict(log.ros or {})
    bag = any(key not in _OWN for key in ros)  # what a bag reader records: frames, mounts
    noise = dict(ros.get("message_noise", {}))
    mounts = ros.get("mounts", {})
    sensors = dict(config.sensors)
    motion = config.motion
    streams = dict(log.streams)
    repairs = dict(log.repairs)
    applied: dict = {}
    for name, block in sensors.items():
        given = explicit(block)
        if "sigma" in given and name in noise and name in streams:
            streams[name] = _drop_columns(streams[name], noise.pop(name))
        if not isinstance(block, GpsOptions):
            continue
        changes = {}
        if "lever_arm" not in given and name in mounts:
            changes["lever_arm"] = (float(mounts[name][0]), float(mounts[name][1]))
            applied[f"sensors.{name}.lever_arm"] = list(changes["lever_arm"])
        if bag and "robust" not in given and block.gate is not None:
            changes["robust"] = ("huber", ROBUST_DEFAULT_K["huber"])
            applied[f"sensors.{name}.robust"] = list(changes["robust"])
        s = streams.get(name)
        if block.datum is None and s is not None and len(s) and {"lat", "lon"} <= set(s.columns):
            changes["datum"] = (float(s["lat"][0]), float(s["lon"][0]))
            applied[f"sensors.{name}.datum"] = list(changes["datum"])
            repairs[f"{name}.datum_first_fix"] = 1
        if changes:
            sensors[name] = _replace(block, changes)
    odo = streams.get("odometry")
    if (
        config.robot.get("drive") == "increments"
        and odo is not None
        and {"var_ds", "var_dtheta"} <= set(odo.columns)
        and not {"k", "k_l", "k_r", "var_floor"} & explicit(motion)
    ):
        floor = (float(np.median(odo["var_ds"])), float(np.median(odo["var_dtheta"])))
        motion = _replace(motion, {"k": (0.0, 0.0), "var_floor": floor})
        applied["motion.var_floor"] = list(floor)
    ros["message_noise"] = noise
    ros["defaults"] = {**ros.get("defaults", {}), **applied}  # a second pass keeps the first's
    config = dataclasses.replace(config, sensors=sensors, motion=motion)
    log = dataclasses.replace(log, streams=streams, repairs=repairs, ros=ros)
    return config, log


#: The keys of ``SensorLog.ros`` that :func:`apply_log_defaults` itself writes.
_OWN = ("message_noise", "defaults")


def _replace(block, changes: dict):
    """``block`` with ``changes``; the keys the config gave stay marked as given."""
    new = dataclasses.replace(block, **changes)
    object.__setattr__(new, "_explicit", explicit(block))
    return new
