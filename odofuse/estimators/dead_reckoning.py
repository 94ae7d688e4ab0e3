"""Dead reckoning: the motion model alone, with the Siegwart covariance growth."""

from __future__ import annotations

from odofuse.estimators.common import initial_state, odometry_inputs, odometry_stream_name
from odofuse.motion import dead_reckon, motion_model_from_config
from odofuse.trajectory import EstimateResult, Trajectory


def run(log, config) -> EstimateResult:
    """Integrate the log's odometry from the initial state (vectorised, with covariance)."""
    model = motion_model_from_config(config)
    t, U = odometry_inputs(log, model)
    pose0, P0 = initial_state(config, log)
    poses, covs = dead_reckon(model, pose0, P0, U)
    stream = odometry_stream_name(model)
    return EstimateResult("dead_reckoning", Trajectory(t, poses, covs), used={stream: len(U)})
