"""Dead reckoning: the motion model alone, with the Siegwart covariance growth.

Its own tell-tale (issue 10): where the log has a gyro, the gyro's and the wheels' heading
changes are compared over short windows
(:func:`odofuse.estimators.pose_checks.gyro_wheel_findings`);
a disagreement the error models cannot explain (wheel slip, a stuck encoder, a gyro fault)
becomes a finding, since dead reckoning keeps every such error.
"""

from __future__ import annotations

import numpy as np

from odofuse.estimators import pose_checks
from odofuse.estimators.common import initial_state, odometry_inputs, odometry_stream_name
from odofuse.estimators.compiled.dead_reckoning import dead_reckon
from odofuse.motion import motion_model_from_config
from odofuse.trajectory import EstimateResult, Trajectory


def _heading_steps(model, U) -> tuple[np.ndarray, np.ndarray]:
    """Wheel heading change (rad) and its error-model variance (rad^2) of each step."""
    d, v = np.empty(len(U)), np.empty(len(U))
    for k, u in enumerate(U):
        delta, J = model.increment(u)
        d[k] = delta[2]
        v[k] = (J[2] ** 2) @ model.errors.variances(model.drive, u)
    return d, v


def run(log, config) -> EstimateResult:
    """Integrate the log's odometry from the initial state (vectorised, with covariance)."""
    model = motion_model_from_config(config)
    t, U = odometry_inputs(log, model)
    pose0, P0 = initial_state(config, log)
    mode = config.estimator_options("dead_reckoning").compiled
    poses, covs = dead_reckon(model, pose0, P0, U, mode=mode)  # numba core or numpy
    stream = odometry_stream_name(model)
    findings = []
    gyro = log.streams.get("gyro")
    if gyro is not None and len(gyro) > 1 and "wz" in gyro.columns:
        opts = config.estimator_options("dead_reckoning")
        sigma = float(getattr(config.sensors.get("gyro"), "sigma", 0.0) or 0.0)
        d, v = _heading_steps(model, U)
        findings = pose_checks.gyro_wheel_findings(t, d, v, gyro.t, gyro["wz"], sigma, opts)
    return EstimateResult(
        "dead_reckoning",
        Trajectory(t, poses, covs),
        used={stream: len(U)},
        findings=tuple(findings),
    )
