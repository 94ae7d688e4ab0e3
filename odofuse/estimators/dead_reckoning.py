"""Dead reckoning: the motion model alone, with the Siegwart covariance growth.

Its own tell-tale (issue 10): where the log has a gyro, the gyro's and the wheels' heading
changes are compared over short windows
(:func:`odofuse.status.pose_checks.gyro_wheel_findings`);
a disagreement the error models cannot explain (wheel slip, a stuck encoder, a gyro fault)
becomes a finding, since dead reckoning keeps every such error.

Systematic errors (issue 11): with ``options.dead_reckoning.odometry_calibration`` declared,
the covariance also carries the prior of the odometry's systematic errors (ds/dtheta scale and
heading bias, or wheel-radius ratio and track scale: :mod:`odofuse.estimators.odocal`), which
dead reckoning never observes (:func:`calibration_covariances`). The poses do not change;
without the option the run is bit-identical to the plain one.
"""

from __future__ import annotations

import numpy as np

from odofuse import se2
from odofuse.estimators.common import initial_state, odometry_inputs, odometry_stream_name
from odofuse.estimators.compiled.dead_reckoning import dead_reckon
from odofuse.estimators.odocal import filter_odometry_calibration
from odofuse.motion import motion_model_from_config
from odofuse.status import pose_checks
from odofuse.trajectory import EstimateResult, Trajectory


def _heading_steps(model, U) -> tuple[np.ndarray, np.ndarray]:
    """Wheel heading change (rad) and its error-model variance (rad^2) of each step, all steps
    at once (the model's increment and error model take ``(N, n)`` inputs; a loop over the
    steps took 57 us a step, 0.27 s of a 94 s log's run)."""
    U = np.asarray(U, dtype=float)
    if not len(U):
        return np.empty(0), np.empty(0)
    delta, J = model.increment(U)
    J2 = J[:, 2]
    return delta[:, 2].copy(), (J2 * J2 * model.errors.variances(model.drive, U)).sum(axis=1)


#: Draws of the systematic errors' prior (scrambled Sobol points, seeded: the result is
#: deterministic); in the linear regime the covariance is within 0.9 % of the exact
#: ``J Sigma_p J^T`` (each step's largest entry; 3 % with 64 draws, 0.3 % with 1024).
CALIBRATION_DRAWS = 256


def calibration_covariances(model, cal, pose0, t, U, poses, mode: str = "auto") -> np.ndarray:
    """Pose covariance ``(N+1, 3, 3)`` of the unobserved systematic errors' prior.

    The second moment, about the estimate ``poses``, of the poses dead-reckoned with the
    calibrated inputs ``cal.apply(U, p, dt)`` over the prior ``p ~ N(cal.nominal,
    diag(cal.sigma)^2)`` (constant over the run), by quasi-Monte Carlo:
    :data:`CALIBRATION_DRAWS` scrambled Sobol points (seed 0) mapped through the normal
    quantile, heading differences wrapped. For small sigmas this is ``J Sigma_p J^T``, the
    augmented EKF's prediction without measurements (tested); unlike that linearisation (or a
    sigma-point rule) it stays faithful where a heading bias or a wheel-radius ratio builds
    radians of heading uncertainty (docs/filters.md, "Dead reckoning and systematic errors").
    The random walk of the filters' calibration states is not modelled.

    Parameters
    ----------
    model : MotionModel
    cal : FilterOdometryCalibration
    pose0 : ndarray (3,)
        Initial pose (m, m, rad), world frame.
    t : ndarray (N+1,)
        Odometry times (s); ``dt`` of the heading bias.
    U : ndarray (N, n)
        Drive inputs.
    poses : ndarray (N+1, 3)
        The dead-reckoned estimate (nominal parameters).
    mode : str
        ``options.dead_reckoning.compiled``.

    Returns
    -------
    ndarray (N+1, 3, 3)
        To be added to the white-noise covariance of the same poses (independent sources).
    """
    upper = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    acc = np.zeros((6, len(poses)))
    for dev in calibration_deviations(model, cal, pose0, t, U, poses, mode):
        d = dev.T
        for row, (a, b) in zip(acc, upper, strict=True):
            row += d[a] * d[b]
    C = np.empty((len(poses), 3, 3))
    for row, (a, b) in zip(acc, upper, strict=True):
        C[:, a, b] = C[:, b, a] = row / CALIBRATION_DRAWS
    return C


def calibration_deviations(model, cal, pose0, t, U, poses, mode: str = "auto"):
    """The poses dead-reckoned with each of :func:`calibration_covariances`' draws of the
    systematic errors' prior, minus ``poses`` (``(N+1, 3)`` each, heading wrapped), one draw
    at a time: their second moment is that covariance (and, between two times, the
    correlation the shared errors give, which ``benchmarks/bench_status.py`` reads)."""
    from scipy.stats import norm, qmc

    nominal, sigma = np.asarray(cal.nominal), np.asarray(cal.sigma)
    dt = np.diff(np.asarray(t, dtype=float))
    z = norm.ppf(qmc.Sobol(len(nominal), scramble=True, seed=0).random(CALIBRATION_DRAWS))
    for zi in z:
        Uc = cal.apply(U, nominal + zi * sigma, dt)
        q, _ = dead_reckon(model, pose0, np.zeros((3, 3)), Uc, False, mode)
        d = q - poses
        d[:, 2] = se2.wrap(d[:, 2])
        yield d


def run(log, config) -> EstimateResult:
    """Integrate the log's odometry from the initial state (vectorised, with covariance)."""
    model = motion_model_from_config(config)
    t, U = odometry_inputs(log, model)
    pose0, P0 = initial_state(config, log)
    opts = config.estimator_options("dead_reckoning")
    mode = opts.compiled
    poses, covs = dead_reckon(model, pose0, P0, U, mode=mode)  # numba core or numpy
    cal = filter_odometry_calibration(model, opts, "options.dead_reckoning", config.source)
    if cal is not None:
        covs += calibration_covariances(model, cal, pose0, t, U, poses, mode)
    stream = odometry_stream_name(model)
    findings = []
    gyro = log.streams.get("gyro")
    if gyro is not None and len(gyro) > 1 and "wz" in gyro.columns:
        sigma = float(getattr(config.sensors.get("gyro"), "sigma", 0.0) or 0.0)
        d, v = _heading_steps(model, U)
        findings = pose_checks.gyro_wheel_findings(t, d, v, gyro.t, gyro["wz"], sigma, opts)
    return EstimateResult(
        "dead_reckoning",
        Trajectory(t, poses, covs),
        used={stream: len(U)},
        findings=tuple(findings),
    )
