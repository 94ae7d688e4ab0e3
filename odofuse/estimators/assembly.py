"""The offline run of a filter: a :class:`~odofuse.estimators.localizer.Localizer` built for
a whole log and fed every reading of it.

Owns :func:`build` (:func:`~odofuse.estimators.localizer.assemble` for a whole log, with its
odometry times and inputs), :func:`feed` (every event of a log in time order) and
:func:`run_with` (the offline ``run`` of the EKF, UKF and particle filter), so the offline and
the online results are the same by construction.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.errors import NumericError, OdofuseError, one_line
from odofuse.estimators.common import events
from odofuse.estimators.localizer import Localizer, assemble
from odofuse.trajectory import EstimateResult


def build(config, log, estimator: str, make_backend):
    """Localizer for a whole ``log``, plus the log's odometry times and drive inputs.

    Returns
    -------
    loc : Localizer
        Starting at ``t[0]``, the initial time.
    t : ndarray (N+1,)
        Odometry times (``t[0]`` the initial time).
    U : ndarray (N, n)
        Drive inputs per step.
    """
    from odofuse.estimators.common import odometry_inputs
    from odofuse.motion import motion_model_from_config

    t, U = odometry_inputs(log, motion_model_from_config(config))
    return assemble(config, estimator, make_backend, float(t[0]), log), t, U


def feed(loc: Localizer, log, t, U, streams, config=None) -> Localizer:
    """Feed every event of ``log`` to ``loc`` in time order, then :meth:`Localizer.finish`.

    An event that makes the back end raise on a non-finite number (filterpy's
    ``array must not contain infs or NaNs``, a failed Cholesky) ends the run with a
    :class:`~odofuse.errors.NumericError` naming the time, the stream and the likely cause
    (:func:`numeric_cause`); a state that turns non-finite without an exception is found in
    the trajectory by :func:`odofuse.estimators.run_estimator`.
    """
    te, what, step = float(t[0]), "odometry", None
    # an overflow is reported below as a NumericError, not as numpy's RuntimeWarning
    with np.errstate(over="ignore", invalid="ignore"):
        try:
            for te, kind, stream, i in events(log, t, U, streams):
                if kind == 1:
                    what, step = "odometry", i
                    loc.add_odometry(te, U[i])
                else:
                    what, step = stream, None
                    loc.add_measurement(stream, log.streams[stream].row(i))
            te, what, step = float(t[-1]), "end of log", None
            loc.finish()
        except OdofuseError:
            raise
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            cause = numeric_cause(_last_finite_cov(loc), U[step] if step is not None else None)
            name = getattr(loc, "name", None) or "filter"
            raise NumericError(f"{one_line(exc)}; {cause}", name, float(te), what) from None
    return loc


def _last_finite_cov(loc) -> np.ndarray:
    """The last finite pose covariance the localizer recorded (NaN if none)."""
    try:
        covs = loc.trajectory().covariances
    except Exception:  # noqa: BLE001 - a failing run: the hint must not raise again
        covs = None
    if covs is None or not len(covs):
        return np.full((3, 3), np.nan)
    ok = np.flatnonzero(np.isfinite(covs).all(axis=(1, 2)))
    return covs[ok[-1]] if len(ok) else np.full((3, 3), np.nan)


def numeric_cause(P, u=None, dt=None) -> str:
    """The most likely cause of a numeric failure that can be tested, as a hint naming keys.

    ``P`` is the last pose covariance (finite or not), ``u`` the failing step's drive input
    and ``dt`` its length (s), when known. In this order: ``P`` had overflowed (> 1e12: wheel
    increments implausible for the configured units, the encoder scale and wheel radius, a
    step's speed against ``log.max_speed``); ``P`` was not positive definite (its smallest
    eigenvalue: the noise numbers); the step's input size; else a noise parameter at a bound.
    """
    P3 = np.asarray(P, dtype=float)[:3, :3]
    units = (
        "the wheel increments may be implausible for the units (check robot.wheel_radius, "
        "robot.encoder.ticks_per_rev; log.max_speed bounds a step's speed)"
    )
    if np.isfinite(P3).all():
        w = np.linalg.eigvalsh(0.5 * (P3 + P3.T))
        if np.abs(w).max() > 1e12:
            return f"the pose covariance had grown to {np.abs(w).max():.3g}: {units}"
        if w.min() <= 0:
            return (
                f"the pose covariance had lost positive definiteness (smallest eigenvalue "
                f"{w.min():.3g}): the noise numbers (motion.k*, sensors.*.sigma) may not fit "
                "the data"
            )
    if u is not None and len(u) and math.isfinite(float(np.max(np.abs(u)))):
        per = f" in {dt:.3g} s" if dt else ""
        return f"the step's largest input is {float(np.max(np.abs(u))):.3g}{per}: {units}"
    return (
        "a noise parameter at a bound? (a very small or very large motion.k* or "
        "sensors.*.sigma lets the covariance overflow)"
    )


def run_with(log, config, estimator: str, make_backend) -> EstimateResult:
    """Offline run: a thin wrapper that feeds the whole log to a :class:`Localizer`."""
    loc, t, U = build(config, log, estimator, make_backend)
    streams = [s for s in config.sensors if s in log.streams]
    feed(loc, log, t, U, streams, config)
    return loc.result()
