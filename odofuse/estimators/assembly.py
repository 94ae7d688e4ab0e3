"""The offline run of a filter: a :class:`~odofuse.estimators.localizer.Localizer` built for
a whole log and fed every reading of it.

Owns :func:`build` (:func:`~odofuse.estimators.localizer.assemble` for a whole log, with its
odometry times and inputs), :func:`feed` (every event of a log in time order) and
:func:`run_with` (the offline ``run`` of the EKF, UKF and particle filter), so the offline and
the online results are the same by construction.
"""

from __future__ import annotations

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


def feed(loc: Localizer, log, t, U, streams) -> Localizer:
    """Feed every event of ``log`` to ``loc`` in time order, then :meth:`Localizer.finish`."""
    for te, kind, stream, i in events(log, t, U, streams):
        if kind == 1:
            loc.add_odometry(te, U[i])
        else:
            loc.add_measurement(stream, log.streams[stream].row(i))
    loc.finish()
    return loc


def run_with(log, config, estimator: str, make_backend) -> EstimateResult:
    """Offline run: a thin wrapper that feeds the whole log to a :class:`Localizer`."""
    loc, t, U = build(config, log, estimator, make_backend)
    streams = [s for s in config.sensors if s in log.streams]
    feed(loc, log, t, U, streams)
    return loc.result()
