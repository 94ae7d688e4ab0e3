"""Estimators: each is ``run(log, config) -> EstimateResult``, looked up by name.

The table maps a config name to ``"module:function"`` so that importing odofuse does not import
gtsam or filterpy until an estimator that needs them runs. Users may name their own estimator
as ``"package.module:function"``.
"""

from __future__ import annotations

import dataclasses

from odofuse.errors import ConfigError
from odofuse.plugins import load_function

ESTIMATORS: dict[str, str] = {
    "dead_reckoning": "odofuse.estimators.dead_reckoning:run",
    "ekf": "odofuse.estimators.ekf:run",
    "ukf": "odofuse.estimators.ukf:run",
    "particle": "odofuse.estimators.particle:run",
    "smoother": "odofuse.estimators.graph:run_smoother",
    "isam2": "odofuse.estimators.graph:run_isam2",
    "fixed_lag": "odofuse.estimators.graph:run_fixed_lag",
}


def get_estimator(name: str):
    """The ``run(log, config)`` of estimator ``name`` (a table key or ``module:function``)."""
    spec = ESTIMATORS.get(name, name)
    if ":" not in spec:
        raise ConfigError(
            f"unknown estimator '{name}'; known: {', '.join(ESTIMATORS)}", key="estimator"
        )
    return load_function(spec, "estimator")


def _check_arguments(name, log, config) -> None:
    """One-line :class:`~odofuse.errors.InputError` for arguments of the wrong kind."""
    from odofuse.config import RunConfig
    from odofuse.errors import InputError
    from odofuse.io.log import SensorLog

    if not isinstance(name, str):
        raise InputError(f"argument 'name': expected an estimator name (str), got {name!r}")
    if not isinstance(log, SensorLog):
        raise InputError(
            f"argument 'log': expected a SensorLog (odofuse.io.loader.load_log_for(config)), "
            f"got {type(log).__name__}"
        )
    if not isinstance(config, RunConfig):
        raise InputError(
            f"argument 'config': expected a RunConfig (odofuse.config.load_config(path)), "
            f"got {type(config).__name__}"
        )


def _check_finite(name: str, result) -> None:
    """A :class:`~odofuse.errors.NumericError` at the first pose whose estimate or covariance
    is not finite (any estimator, compiled or not): never a NaN in the outputs."""
    import numpy as np

    traj = result.trajectory
    bad = ~np.isfinite(traj.poses).all(axis=1)
    if traj.covariances is not None:
        bad |= ~np.isfinite(traj.covariances).all(axis=(1, 2))
    if not bad.any():
        return
    from odofuse.errors import NumericError
    from odofuse.estimators.assembly import numeric_cause

    k = int(np.argmax(bad))
    P = traj.covariances[k - 1] if traj.covariances is not None and k else np.full((3, 3), np.nan)
    dt = float(traj.t[k] - traj.t[k - 1]) if k else None
    raise NumericError(
        f"the estimate or its covariance is not finite, first here ({int(bad.sum())} of "
        f"{len(bad)} poses); {numeric_cause(P, None, dt)}",
        name,
        float(traj.t[k]),
        "the step ending here",
    )


def _unused_streams(result, config, streams):
    """A configured stream with data that the estimator counted but never used or rejected
    (all its readings outside the odometry's time span, say) degrades the run unless a
    degrading finding already names it: ``used: 0`` never hides behind ``ok``."""
    from odofuse.status.findings import Finding

    notes = []
    explained = {f.sensor for f in result.findings if f.degrades}
    for s in getattr(config, "sensors", {}) or {}:
        if s in explained:
            continue
        n = len(streams[s]) if s in streams else 0
        if n and s in result.used and not result.used[s] and not result.rejected.get(s, 0):
            t = streams[s].t
            notes.append(
                Finding(
                    "unused",
                    f"none of its {n} readings ({t[0]:.2f}-{t[-1]:.2f} s) was used or rejected: "
                    "outside the odometry's time span, or another clock?",
                    sensor=s,
                    figure=0.0,
                )
            )
    return (
        dataclasses.replace(result, findings=tuple(result.findings) + tuple(notes))
        if notes
        else result
    )


def run_estimator(name: str, log, config, **options):
    """Run estimator ``name`` on ``log`` with ``config``; returns an ``EstimateResult``.

    ``options`` are keyword arguments of that estimator's ``run`` beyond the config (the
    cross-check asks the batch smoother for its error samples: ``error_samples=K``).

    The log's plausibility findings (``log.findings``) join the result's. A log with loop
    closures (``loop_closures`` stream) that the estimator did not use gets
    a non-degrading finding saying so (only the graph estimators use them, with
    ``sensors: {loop_closures: {}}``).
    """
    _check_arguments(name, log, config)
    result = get_estimator(name)(log, config, **options)
    _check_finite(name, result)
    noted = tuple(getattr(log, "findings", ()) or ())  # the log's plausibility findings
    if noted:
        result = dataclasses.replace(result, findings=tuple(result.findings) + noted)
    from odofuse.status import latency

    if name in latency.OWN:  # the time-stamp test on the graph's own residuals
        found, block = latency.findings(config, log, result)
        if block:
            extra = {**(result.extra or {}), "time_offset": block}
            result = dataclasses.replace(
                result, findings=tuple(result.findings) + tuple(found), extra=extra
            )
    streams = getattr(log, "streams", {}) or {}
    result = _unused_streams(result, config, streams)
    n = len(streams["loop_closures"]) if "loop_closures" in streams else 0
    if n and "loop_closures" not in result.used:
        from odofuse.status.findings import Finding

        note = Finding(
            "loop_closures",
            f"{n} loop closures in the log are not used by '{name}' (the graph estimators use "
            "them with sensors: {loop_closures: {}})",
            sensor="loop_closures",
            figure=float(n),
            degrades=False,
        )
        result = dataclasses.replace(result, findings=tuple(result.findings) + (note,))
    return result
