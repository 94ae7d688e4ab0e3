"""Batch solving of the graph, and the results every graph solver returns.

Owns :func:`build_graph` (the whole graph with its dead-reckoned / SLAM-initialised values),
the batch smoother :func:`run_smoother` (GTSAM's Levenberg-Marquardt for graphs of built-in
factors, :func:`levenberg_marquardt` when the graph holds Python factors) and the conversion
of a solution into an :class:`~odofuse.trajectory.EstimateResult` (:func:`finish`: keyframe
poses, world-frame marginal covariances, calibration, landmarks, outlier counts). The
incremental solvers are in :mod:`odofuse.estimators.graph.isam2`.

Why a Python LM loop: GTSAM's C++ optimisers release the GIL and linearise on TBB worker
threads, so every ``CustomFactor`` callback has to re-acquire the GIL from a foreign thread.
Measured on Plaza1 (3529 calibrated range factors, 2 cores): one ``LevenbergMarquardtOptimizer``
iteration took ~4 s, while ``graph.linearize`` called from Python took 0.035 s and the sparse
solve 0.05 s. The loop :func:`levenberg_marquardt` calls exactly those (linearise, damp,
eliminate, retract) and is used whenever the graph holds Python factors; graphs of built-in
factors use GTSAM's own LM.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from odofuse import se2
from odofuse.estimators.graph.factors import Factors
from odofuse.estimators.graph.isam2_slam import incremental_slam
from odofuse.estimators.graph.keys import X, model_kind
from odofuse.estimators.graph.marginals import batch_marginals
from odofuse.estimators.graph.problem import GraphProblem, build_problem
from odofuse.trajectory import EstimateResult, Trajectory


def levenberg_marquardt(
    graph, values, dims, max_iterations=100, relative_tolerance=1e-6, lambda_initial=1e-5
):
    """Minimise ``graph.error`` from ``values`` by Levenberg-Marquardt (Python driven).

    Each iteration linearises once, then solves ``(J^T J + lambda I) dx = -J^T r`` (the
    damping added as unit-weight prior rows on every variable) by sparse QR/Cholesky
    elimination in a COLAMD ordering fixed at the start, retracts, and accepts the step if
    the error decreases (lambda / 10), else retries with lambda * 10.

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph
    values : gtsam.Values
        Initial estimate (not modified).
    dims : dict
        Key -> tangent dimension of every variable.
    max_iterations : int
    relative_tolerance : float
        Stop when an accepted step lowers the error by less than this fraction.
    lambda_initial : float

    Returns
    -------
    values : gtsam.Values
        The optimum.
    iterations : int
    error : float
        ``graph.error`` at the optimum.
    """
    import gtsam

    err = graph.error(values)
    lin = graph.linearize(values)
    ordering = gtsam.Ordering.Colamd(gtsam.VariableIndex(lin))
    units = {n: gtsam.noiseModel.Unit.Create(n) for n in set(dims.values())}
    eyes = {n: np.eye(n) for n in units}
    zeros = {n: np.zeros(n) for n in units}
    lam = float(lambda_initial)
    iterations = 0
    for iterations in range(1, int(max_iterations) + 1):
        if iterations > 1:
            lin = graph.linearize(values)
        improved = False
        while lam <= 1e10:
            damped = lin.clone()
            sq = math.sqrt(lam)
            for key, n in dims.items():
                damped.add(gtsam.JacobianFactor(key, sq * eyes[n], zeros[n], units[n]))
            delta = damped.optimize(ordering)
            trial = values.retract(delta)
            trial_err = graph.error(trial)
            if trial_err <= err:
                decrease = (err - trial_err) / max(err, 1e-300)
                values, err = trial, trial_err
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved or decrease < relative_tolerance:
            break
    return values, iterations, float(err)


def pose_array(values, K) -> np.ndarray:
    out = np.empty((K, 3))
    for i in range(K):
        p = values.atPose2(X(i))
        out[i] = (p.x(), p.y(), p.theta())
    out[:, 2] = se2.wrap(out[:, 2])
    return out


def _extra(problem: GraphProblem, fac: Factors, values, estimator: str) -> dict:
    extra: dict = {"keyframes": int(len(problem.kt)), "python_factors": fac.python_factors}
    cal = {}
    for name, (key, _, _) in problem.calib.items():
        if values.exists(key):
            cal[name] = float(values.atVector(key)[0])
    oc = problem.odometry_calibration
    if oc is not None and values.exists(problem.odometry_key):
        vec = values.atVector(problem.odometry_key)
        cal.update({n: float(x) for n, x in zip(oc.names, vec, strict=True)})
    if cal:
        extra["calibration"] = cal
    if problem.options.slam:
        extra["landmarks"] = {
            int(lid): [float(c) for c in values.atPoint2(key)]
            for lid, key in fac.landmark_keys.items()
            if values.exists(key)
        }
    return extra


def _outliers(problem: GraphProblem, fac: Factors, values) -> dict[str, int]:
    """Per stream: factors whose whitened residual exceeds the model's chi-square gate."""
    from odofuse.measurements import gate_threshold

    out: dict[str, int] = {}
    thresholds: dict[tuple, float] = {}
    for meas, f in fac.created:
        m = problem.models[meas.stream]
        if getattr(m, "gate", None) is None:
            continue
        e = np.atleast_1d(f.unwhitenedError(values)) / fac.error_scale.get(id(f), 1.0)
        R = m.R(meas.row)
        kind = model_kind(m)
        if kind == "GyroYawRate":  # the factor's error is a heading change (rad), R a rate
            e = e / float(meas.row["dt"])
        elif e.size == 2 and kind == "LandmarkRangeBearing":  # GTSAM: (bearing, range)
            e = e[::-1]
        nis = float(e[0] * e[0] / R[0, 0]) if e.size == 1 else float(e @ np.linalg.solve(R, e))
        key = (m.gate, e.size)
        if key not in thresholds:
            thresholds[key] = gate_threshold(m.gate, e.size)
        if nis > thresholds[key]:
            out[meas.stream] = out.get(meas.stream, 0) + 1
    return out


def world_covs(problem, poses, cov_of) -> np.ndarray:
    covs = np.empty((len(poses), 3, 3))
    for i in range(len(poses)):
        covs[i] = se2.cov_body_to_world(poses[i], cov_of(X(i)))
    return 0.5 * (covs + np.swapaxes(covs, 1, 2))


def landmark_covariances(fac: Factors, values, cov_of) -> dict:
    """SLAM landmark id -> ``[var_x, cov_xy, var_y]`` (m^2, world frame) from ``cov_of(key)``."""
    out = {}
    for lid, key in fac.landmark_keys.items():
        if values.exists(key):
            c = cov_of(key)
            out[int(lid)] = [float(c[0, 0]), float(0.5 * (c[0, 1] + c[1, 0])), float(c[1, 1])]
    return out


def finish(problem, fac, values, covs, estimator, extra) -> EstimateResult:
    poses = pose_array(values, len(problem.kt))
    extra = {**_extra(problem, fac, values, estimator), **extra}
    outliers = _outliers(problem, fac, values)
    if outliers:
        extra["outliers"] = outliers
    traj = Trajectory(problem.kt.copy(), poses, covs)
    used = {k: int(v) for k, v in fac.used.items()}
    return EstimateResult(estimator, traj, used, dict(problem.rejected), extra)


def build_graph(problem: GraphProblem):
    """The whole graph and its dead-reckoned / SLAM-initialised values (batch form)."""
    fac = Factors(problem)
    graph, values = fac.static()
    guess = problem.dead_reckoning()
    import gtsam

    for i in range(len(problem.kt)):
        fac.keyframe(i, gtsam.Pose2(*guess[i]), graph, values)
    return fac, graph, values


def incremental_initial_values(problem: GraphProblem, values):
    """``values`` with the poses and landmarks of an iSAM2 SLAM pass (``slam_init``).

    GTSAM's default iSAM2 parameters but QR factorisation (as ``estimator: isam2``); a
    landmark the pass could not fix keeps its dead-reckoned initial value. Returns the values
    and ``{"init_s": s}`` (its wall time).
    """
    import gtsam

    t0 = time.perf_counter()
    rejected = dict(problem.rejected)
    params = gtsam.ISAM2Params()
    params.setFactorization("QR")  # odometry floors can be too ill-conditioned for Cholesky
    isam, _, _ = incremental_slam(problem, params)
    problem.rejected.clear()
    problem.rejected.update(rejected)  # the batch graph still holds every row
    out = gtsam.Values(values)
    out.update(isam.calculateEstimate())  # every key of the pass is in the batch graph
    return out, {"init_s": time.perf_counter() - t0}


def run_smoother(log, config) -> EstimateResult:
    """Batch Levenberg-Marquardt over the whole log (``estimator: smoother``).

    Returns
    -------
    EstimateResult
        Keyframe poses with world-frame marginal covariances; ``used``/``rejected`` per
        stream; ``extra``: ``calibration`` (state -> value), ``landmarks`` (SLAM: id -> [x, y]),
        ``outliers`` (per stream, beyond the model's gate at the optimum), ``keyframes``,
        ``iterations``, ``final_error``, ``solve_s``.
    """
    import gtsam

    problem = build_problem(log, config, "smoother")
    fac, graph, values = build_graph(problem)
    opts = problem.options
    extra: dict = {}
    calibrated = bool(problem.calib) or problem.odometry_calibration is not None
    if opts.slam and (
        opts.slam_init == "incremental" or (opts.slam_init == "auto" and not calibrated)
    ):
        values, extra = incremental_initial_values(problem, values)
    t0 = time.perf_counter()
    if fac.python_factors:
        result, iterations, err = levenberg_marquardt(
            graph, values, fac.dims, opts.max_iterations, opts.relative_tolerance
        )
    else:
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(opts.max_iterations)
        params.setRelativeErrorTol(opts.relative_tolerance)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        result = optimizer.optimize()
        iterations, err = optimizer.iterations(), graph.error(result)
    solve_s = time.perf_counter() - t0
    covs, notes, cov_of = None, [], None
    if opts.covariances:
        cov_of, notes = batch_marginals(graph, result)
    if cov_of is not None:
        poses = pose_array(result, len(problem.kt))
        covs = world_covs(problem, poses, cov_of)
    extra.update(iterations=int(iterations), final_error=float(err), solve_s=solve_s)
    if cov_of is not None and problem.calib:
        extra["calibration_sigma"] = {
            name: float(np.sqrt(cov_of(key)[0, 0])) for name, (key, _, _) in problem.calib.items()
        }
    if cov_of is not None and problem.options.slam:
        extra["landmark_covariances"] = landmark_covariances(fac, result, cov_of)
    res = finish(problem, fac, result, covs, "smoother", extra)
    return dataclasses.replace(res, findings=tuple(res.findings) + tuple(notes))
