"""Batch solving of the graph, and the results every graph solver returns.

Owns :func:`build_graph` (the whole graph with its dead-reckoned / SLAM-initialised values),
the batch smoother :func:`run_smoother` (GTSAM's Levenberg-Marquardt iterated to odofuse's
stopping rule, :func:`_gtsam_lm`, for graphs of built-in factors; :func:`levenberg_marquardt`
when the graph holds Python factors), its start with loop closures
(:func:`loop_initial_values`: chordal or dead-reckoned, by graph error) and the conversion
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
import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from odofuse import se2
from odofuse.errors import one_line
from odofuse.estimators.graph.chordal import chordal_poses
from odofuse.estimators.graph.factors import Factors
from odofuse.estimators.graph.isam2_slam import cholesky_suits, incremental_slam
from odofuse.estimators.graph.keys import X
from odofuse.estimators.graph.marginals import marginal_covariances
from odofuse.estimators.graph.problem import GraphProblem, build_problem, convex_problem
from odofuse.estimators.graph.time_offset import scores as time_offset_scores
from odofuse.estimators.graph.variance import (
    WhitenedSystem,
    factor_groups,
    variance_components,
)
from odofuse.status.graph_checks import (
    factor_residuals,
    graph_findings,
    residual_summary,
    robust_weights,
    solver_findings,
)
from odofuse.trajectory import EstimateResult, Trajectory


@dataclass(frozen=True)
class LMOutcome:
    """What :func:`levenberg_marquardt` returns.

    ``reason`` is ``"converged"`` (relative decrease below the tolerance, or no step lowers
    the error at any damping: a minimum), ``"max_iterations"`` (the cap was reached while the
    error still fell by more than the tolerance) or ``"no_decrease"`` (no step lowers the
    error and some damped systems could not be eliminated) or ``"non_finite"`` (the error at
    the initial values is not finite); ``indeterminate`` counts the
    eliminations that failed and were retried with ten times the damping.
    """

    values: object
    iterations: int
    error: float
    reason: str
    indeterminate: int = 0
    gauss_newton: int = 0  # Gauss-Newton steps after the LM (polish_isam2)


def levenberg_marquardt(
    graph, values, dims, max_iterations=100, relative_tolerance=1e-6, lambda_initial=1e-5
) -> LMOutcome:
    """Minimise ``graph.error`` from ``values`` by Levenberg-Marquardt (Python driven).

    Each iteration linearises once, then solves ``(J^T J + lambda I) dx = -J^T r`` (the
    damping added as unit-weight prior rows on every variable) by sparse QR/Cholesky
    elimination in a COLAMD ordering fixed at the start, retracts, and accepts the step if
    the error decreases (lambda / 10), else retries with lambda * 10. The elimination is
    GTSAM's default (Cholesky where it can), and QR where Cholesky meets an indeterminate
    system (:func:`_solve_damped`); once Cholesky has refused a system at some lambda, every
    later system at that lambda or below goes to QR directly (the information matrix's
    condition number only falls as the damping grows; on Plaza2's calibrated range-only SLAM
    the refused attempts were 83 of 139 and 1.3 s of a 16 s run). A system that fails both
    ways (a singular block, a non-finite Jacobian) is retried with lambda * 10 too, and
    counted.

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
    LMOutcome
    """
    import gtsam

    err = graph.error(values)
    if not math.isfinite(err):
        return LMOutcome(values, 0, float(err), "non_finite")
    lin = graph.linearize(values)
    ordering = gtsam.Ordering.Colamd(gtsam.VariableIndex(lin))
    units = {n: gtsam.noiseModel.Unit.Create(n) for n in set(dims.values())}
    eyes = {n: np.eye(n) for n in units}
    zeros = {n: np.zeros(n) for n in units}
    damping: dict[float, object] = {}  # lambda -> its prior rows (lambda takes a few values)

    def damping_rows(lam: float):
        rows = damping.get(lam)
        if rows is None:
            rows = damping[lam] = gtsam.GaussianFactorGraph()
            sq = math.sqrt(lam)
            for key, n in dims.items():
                rows.add(gtsam.JacobianFactor(key, sq * eyes[n], zeros[n], units[n]))
        return rows

    lam = float(lambda_initial)
    refused = -math.inf  # the largest lambda at which Cholesky refused a damped system
    iterations = 0
    failed = 0
    reason = "max_iterations"
    for iterations in range(1, int(max_iterations) + 1):
        if iterations > 1:
            lin = graph.linearize(values)
        improved = False
        while lam <= 1e10:
            damped = lin.clone()
            damped.push_back(damping_rows(lam))
            delta, cholesky_refused = _solve_damped(damped, ordering, cholesky=lam > refused)
            if cholesky_refused:
                refused = max(refused, lam)
            if delta is None:
                failed += 1
                lam *= 10.0
                continue
            trial = values.retract(delta)
            trial_err = graph.error(trial)
            if trial_err <= err:
                decrease = (err - trial_err) / max(err, 1e-300)
                values, err = trial, trial_err
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved:
            reason = "no_decrease" if failed else "converged"
            break
        if decrease < relative_tolerance:
            reason = "converged"
            break
    return LMOutcome(values, iterations, float(err), reason, failed)


def _solve_damped(damped, ordering, cholesky: bool = True):
    """``(delta, refused)``: the solution of the damped linear system ``damped`` (a
    ``GaussianFactorGraph``) in ``ordering``, or None when it cannot be had, and whether
    Cholesky refused the system.

    GTSAM's default elimination (``EliminatePreferCholesky``, tried when ``cholesky``)
    factorises the information matrix, whose condition number is the square of the
    Jacobian's; where it meets an indeterminate system, QR (``gtsam.EliminateQR``, on the
    Jacobian) is tried before the caller raises the damping. Plaza2's calibrated range-only
    SLAM met Cholesky's failure at lambda 1e-3 in most of its iterations, so each took a 10x
    damped step and LM stopped at its 100-iteration cap still falling (docs/trust.md, session
    36). None when QR fails too or gives a non-finite step."""
    import gtsam

    refused = False
    if cholesky:
        try:
            return damped.optimize(ordering), False
        except RuntimeError:  # gtsam.IndeterminateLinearSystemException
            refused = True
    try:
        delta = damped.optimize(ordering, gtsam.EliminateQR)
    except RuntimeError:
        return None, refused
    return (delta if np.all(np.isfinite(delta.vector())) else None), refused


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
    for name in problem.calib:  # a walking bias: its value at the end of the log
        key = problem.final_key(name)
        if values.exists(key):
            cal[name] = float(values.atVector(key)[0])
    walks = {
        name: {
            "bias_walk": float(walk),
            "segments": int(len(problem.kt) - 1),
            "first": float(values.atVector(problem.calib[name][0])[0]),
        }
        for name, walk in problem.bias_walk.items()
        if values.exists(problem.calib[name][0])
    }
    if walks:
        extra["calibration_walk"] = walks
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


def _calibration_states(problem: GraphProblem, values) -> list[tuple[tuple[str, ...], int]]:
    """``(names, key)`` of the run's calibration states in ``values``: each sensor state's
    final key (one name) and the odometry calibration vector (its names, in order)."""
    states = [((name,), problem.final_key(name)) for name in problem.calib]
    if problem.odometry_calibration is not None:
        states.append((problem.odometry_calibration.names, problem.odometry_key))
    return [(names, key) for names, key in states if values.exists(key)]


def calibration_keys(problem: GraphProblem, values) -> list:
    """The keys of the run's calibration states in ``values`` (:func:`_calibration_states`)."""
    return [key for _, key in _calibration_states(problem, values)]


def calibration_sigmas(problem: GraphProblem, values, cov_of) -> dict:
    """``{"calibration_sigma": {name: sigma}}`` of the calibration states in ``values``
    (``cov_of(key)`` their marginal covariance), beside ``extra["calibration"]``'s values: the
    sensors' states and the wheels' (:mod:`odofuse.status.geometry` advises from them); empty
    when there are none."""
    sigma = {}
    for names, key in _calibration_states(problem, values):
        sd = np.sqrt(np.diag(cov_of(key))[: len(names)])
        sigma.update({n: float(v) for n, v in zip(names, sd, strict=True)})
    return {"calibration_sigma": sigma} if sigma else {}


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


#: Called as ``on_solution(problem, graph, values, estimator)`` by :func:`finish` with the
#: graph a run solved and its solution (the batch smoother's, iSAM2's final graph), or for
#: the fixed-lag smoother's stitched poses every factor it was given and its final values
#: (each pose the estimate of the factors of the keyframes before it left the window):
#: ``benchmarks/bench_status.py`` sets it to compute the NEES bound that the estimator's own
#: model implies for the run. None in every run of odofuse.
on_solution = None


def finish(
    problem, fac, values, covs, estimator, extra, findings=(), stitched=False, graph=None
) -> EstimateResult:
    """The :class:`EstimateResult` of a solution, with the graph's own findings.

    ``extra`` gains ``calibration``, ``landmarks`` (SLAM), ``keyframes``, ``python_factors``,
    ``outliers`` (per stream, factors beyond the model's gate) and ``residuals`` (per stream:
    factors, chi-square per dimension, median ratio, fraction beyond 0.999); ``findings``
    (solver, covariance) are followed by :func:`~odofuse.status.graph_checks.graph_findings`
    (``stitched``: poses from several solutions, the fixed-lag smoother's; ``graph``: the graph
    ``values`` solves, or the stitched run's factors, for :data:`on_solution`).
    """
    if on_solution is not None and graph is not None:
        on_solution(problem, graph, values, estimator)
    poses = pose_array(values, len(problem.kt))
    extra = {**_extra(problem, fac, values, estimator), **extra}
    residuals = factor_residuals(problem, fac, values)
    summary = residual_summary(problem, residuals)
    outliers = {s: v["outliers"] for s, v in summary.items() if v.get("outliers")}
    if outliers:
        extra["outliers"] = outliers
    extra["residuals"] = {
        s: {k: v for k, v in d.items() if k != "outliers"} for s, d in summary.items()
    }
    found = graph_findings(problem, values, residuals, summary, stitched, estimator == "smoother")
    findings = tuple(findings) + tuple(found)
    traj = Trajectory(problem.kt.copy(), poses, covs)
    used = {k: int(v) for k, v in fac.used.items()}
    return EstimateResult(estimator, traj, used, dict(problem.rejected), extra, findings)


def build_graph(problem: GraphProblem, fac: Factors | None = None, initial=None):
    """The whole graph and its initial values (batch form).

    ``fac`` defaults to ``Factors(problem)``; ``initial`` (``gtsam.Values``) supplies the
    keyframe poses, else they are dead-reckoned.
    """
    import gtsam

    fac = fac or Factors(problem)
    graph, values = fac.static()
    if initial is None:
        guess = [gtsam.Pose2(*p) for p in problem.dead_reckoning()]
    else:
        guess = [initial.atPose2(X(i)) for i in range(len(problem.kt))]
    if initial is not None:  # calibration vectors and landmarks too, where ``initial`` has them
        for key in list(values.keys()):
            kind = chr(gtsam.Symbol(key).chr())
            if kind != "x" and initial.exists(key):
                vector = kind in ("c", "o")
                values.update(key, initial.atVector(key) if vector else initial.atPoint2(key))
    for i in range(len(problem.kt)):
        fac.keyframe(i, guess[i], graph, values)
    return fac, graph, values


def incremental_initial_values(problem: GraphProblem, values):
    """``values`` with the poses and landmarks of an iSAM2 SLAM pass (``slam_init``).

    GTSAM's default iSAM2 parameters (and ``partial_relinearization_check``: batch LM
    starts from the pass, so its online accuracy matters little; Plaza1_TD.txt 19.2 s -> 12.4 s,
    the same optimum; ``estimator: isam2`` keeps the full check, its polish starting from
    its own estimate) but QR factorisation (as ``estimator: isam2``: odometry
    floors can be too ill-conditioned for Cholesky), or Cholesky first where
    :func:`~odofuse.estimators.graph.isam2_slam.cholesky_suits` allows it (the pass again with
    QR if Cholesky meets an indeterminate system); a landmark the pass could not fix keeps its
    dead-reckoned initial value. Returns the values and ``{"init_s": s}`` (its wall time).
    """
    import gtsam

    t0 = time.perf_counter()
    rejected = dict(problem.rejected)
    for factorization in ("CHOLESKY", "QR") if cholesky_suits(problem) else ("QR",):
        params = gtsam.ISAM2Params()
        params.setFactorization(factorization)
        params.enablePartialRelinearizationCheck = problem.options.partial_relinearization_check
        try:
            isam, _, window, _ = incremental_slam(problem, params)
            break
        except RuntimeError:
            if factorization == "QR":
                raise
    problem.rejected.clear()
    problem.rejected.update(rejected)  # the batch graph still holds every row
    out = gtsam.Values(values)
    out.update(window.estimate(isam))  # every key of the pass is in the batch graph
    return out, {"init_s": time.perf_counter() - t0}


def loop_initial_values(problem: GraphProblem, graph, values):
    """``values`` or its poses replaced by :func:`~odofuse.estimators.graph.chordal.chordal_poses`,
    whichever has the lower ``graph.error``.

    Composed odometry accumulates every step's heading error, and on a long graph with loop
    closures LM from there can crawl for thousands of iterations (``w20000.txt``); the
    chordal relaxation uses the loop closures' headings from the start. The graph error of
    both starts decides, so a graph whose other factors (GPS, landmarks) the relaxation
    ignores keeps dead reckoning when that is better.

    ``values`` may also be an incremental SLAM pass's (its landmarks are kept with either
    set of poses): ``"odometry"`` then names those values.

    Returns
    -------
    values : gtsam.Values
    initial : dict
        ``{"start": "odometry" | "chordal", "odometry_error": e, "chordal_error": e}``.
    """
    import gtsam

    chordal = gtsam.Values(values)
    for i, p in enumerate(chordal_poses(problem)):
        chordal.update(X(i), gtsam.Pose2(*p))
    e_odo, e_chordal = float(graph.error(values)), float(graph.error(chordal))
    start = "chordal" if e_chordal < e_odo else "odometry"
    info = {"start": start, "odometry_error": e_odo, "chordal_error": e_chordal}
    return (chordal if start == "chordal" else values), info


def polish_isam2(graph, values, fac: Factors, opts) -> LMOutcome:
    """Batch LM on an iSAM2 run's whole graph ``graph`` from its estimate ``values``.

    iSAM2 relinearises only the variables whose update exceeds ``relinearize_threshold``,
    even in a forced relinearisation, so its final estimate is the solution of a graph
    linearised at stale points: on Victoria Park its poses were 1.3 cm from the optimum
    but its graph error 17.5 % above it (bearing factors at headings up to 0.1 rad old).
    Every path of ``estimator: isam2`` therefore ends with :func:`_solve` (LM, at most
    ``max_iterations``, ``relative_tolerance``) on every factor given to iSAM2 (the
    marginalised keyframes at their estimate when they left:
    odofuse.estimators.graph.isam2_window); its covariances are then those of that optimum
    (:func:`~odofuse.estimators.graph.marginals.optimum_marginals`).

    A graph of built-in factors then takes GTSAM Gauss-Newton steps (QR) while they lower
    the error (:func:`_gauss_newton_steps`). iSAM2's estimate starts the LM so near the
    optimum that on a flat valley its stopping rule is met within a few iterations, short of
    the optimum in the poses: ``w20000.txt`` (Hessian eigenvalues down to ~1e-12) stopped
    after 4 iterations at 2e-9 relative above GTSAM's best graph error but 0.51 m (pose RMS)
    from its poses; three Gauss-Newton steps from iSAM2's estimate reach 3.3 mm.
    """
    out = _solve(graph, values, fac, opts)
    if not fac.python_factors:
        out = _gauss_newton_steps(graph, out)
    return out


def _gauss_newton_steps(graph, out: LMOutcome, max_steps: int = 10) -> LMOutcome:
    """``out`` (an LM solution) followed by GTSAM Gauss-Newton steps, QR factorisation, while
    each lowers the graph error (at most ``max_steps``): the finish of
    ``benchmarks/gtsam_reference.converged_optimum``, GTSAM's best solution. A step that
    raises the error, or an indeterminate system, ends them; ``out.gauss_newton`` counts the
    steps kept."""
    import gtsam

    params = gtsam.GaussNewtonParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    params.setRelativeErrorTol(0.0)
    params.setAbsoluteErrorTol(0.0)
    gn = gtsam.GaussNewtonOptimizer(graph, out.values, params)
    values, err, steps = out.values, float(out.error), 0
    for _ in range(max_steps):
        try:
            gn.iterate()
        except RuntimeError:  # indeterminate: the LM solution stands
            break
        new = float(gn.error())
        if not new < err:
            break
        values, err, steps = gtsam.Values(gn.values()), new, steps + 1  # a copy (see below)
    if not steps:
        return out
    return dataclasses.replace(out, values=values, error=err, gauss_newton=steps)


def _gtsam_lm(graph, values, opts) -> LMOutcome:
    """GTSAM's ``LevenbergMarquardtOptimizer``, one ``iterate()`` at a time, to this rule:
    converged when an iteration lowers the error by less than ``relative_tolerance`` *and*
    did not lower the damping (lambda).

    GTSAM's own ``optimize()`` stops at the first small relative decrease. On an
    ill-conditioned graph that is often a step held back by the damping, not a minimum:
    ``w20000.txt`` (Hessian eigenvalues down to ~1e-12) from the chordal start stops there
    after 20 iterations at error 18.775, 90 m RMS from the minimum (18.763) that the same
    iterations reach at 55 once lambda has fallen to 1e-16. A small decrease counts only when
    the damping held or rose, i.e. a larger step did not help. GTSAM's tolerances are set
    to 0: with them, ``iterate()`` itself abandons the lambda search when a trial step
    lowers the error by less than them and returns the values unchanged, a stall that
    looked like a minimum 34 m away from it. GTSAM's lambda search also gives up at its
    ``lambdaUpperBound`` (1e5 by default) without trying it; the bound is raised to 1e10, as
    :func:`levenberg_marquardt`'s: at 1e5 an iSAM2 SLAM polish (``bench_slam_status.py
    --real-wheels``, seed 2019) met a failed search in its second iteration, took it for a
    minimum and stopped at error 2,516.3, where the next iteration's step (at lambda 1e5)
    went on to the optimum, 2,411.76. ``reason`` is ``"max_iterations"`` when the cap comes
    first.
    """
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(opts.max_iterations)
    params.setRelativeErrorTol(0.0)  # the rule is applied here; inside ``iterate()`` GTSAM
    params.setAbsoluteErrorTol(0.0)  # gives up its lambda search below these tolerances
    params.setlambdaUpperBound(1e10)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    err, lam = float(optimizer.error()), float(optimizer.lambda_())
    reason = "max_iterations"
    for _ in range(int(opts.max_iterations)):
        optimizer.iterate()
        new, new_lam = float(optimizer.error()), float(optimizer.lambda_())
        small = err - new <= opts.relative_tolerance * max(err, 1e-300)
        err = min(err, new)
        if small and new_lam >= lam:
            reason = "converged"
            break
        lam = new_lam
    # a copy: the values() reference would dangle once the optimiser is collected
    return LMOutcome(gtsam.Values(optimizer.values()), int(optimizer.iterations()), err, reason)


def _solve(graph, values, fac, opts) -> LMOutcome:
    """Batch LM: GTSAM's optimiser (:func:`_gtsam_lm`) for built-in factors,
    :func:`levenberg_marquardt` for graphs with Python factors or when GTSAM's optimiser
    raises (indeterminate system)."""
    if not fac.python_factors:
        try:
            return _gtsam_lm(graph, values, opts)
        except RuntimeError:
            pass
    return levenberg_marquardt(
        graph, values, fac.dims, opts.max_iterations, opts.relative_tolerance
    )


def _convex_start(problem: GraphProblem, opts, factors=Factors, initial=None):
    """Initial values for a graph whose sensor streams have a redescending (Tukey) loss: the
    optimum of its :func:`convex_problem` (Huber at the same thresholds) from ``initial``
    (None: dead reckoning), with the factors ``factors(problem)`` (e.g. stage 1's Gaussian
    odometry); ``initial`` itself when no stream has Tukey's loss.

    Starting the Tukey solve from the Huber optimum keeps it from ignoring the readings that
    correct a dead-reckoned drift: a test scenario went 0.05 m -> 0.135 m RMSE from dead
    reckoning with a Cauchy first step (whose influence also decays) and 0.0465 m with Huber.
    """
    soft = convex_problem(problem)
    if soft is None:
        return initial
    fac, graph, values = build_graph(soft, factors(soft), initial)
    return _solve(graph, values, fac, opts).values


def filter_start(problem: GraphProblem, log, config):
    """The compiled EKF's poses at the keyframe times (heading unwrapped before interpolating),
    as ``gtsam.Values`` of the poses: the smoother's start; None (dead reckoning then) with
    SLAM or loop closures, or where the compiled EKF does not cover the run or fails.

    Why: from the dead-reckoned trajectory of a 25 min log, Levenberg-Marquardt ended in a
    wrong optimum on 8 of 40 simulated runs (position RMSE 5-9 m, all said ``degraded``); from
    the EKF's it ended at a lower graph error on every one tried (RMSE 0.05-0.20 m), and on
    25 nominal 94 s logs both starts reach the same optimum (docs/trust.md, "The geometry
    advice on longer logs"). The compiled EKF costs milliseconds to a fraction of a second."""
    if problem.options.slam or problem.loops or len(problem.kt) < 2:
        return None
    import gtsam

    from odofuse.estimators.compiled import ekf as compiled_ekf

    try:
        result = compiled_ekf.run(log, dataclasses.replace(config, estimator="ekf"))
    except Exception:  # noqa: BLE001 - a start that cannot be had is dead reckoning's
        return None
    if result is None:
        return None
    tr = result.trajectory
    t, poses = np.asarray(tr.t, dtype=float), np.asarray(tr.poses, dtype=float)
    if len(t) < 2 or not np.all(np.isfinite(poses)):
        return None
    cols = (poses[:, 0], poses[:, 1], np.unwrap(poses[:, 2]))
    values = gtsam.Values()
    for i, tk in enumerate(problem.kt):
        x, y, th = (float(np.interp(tk, t, c)) for c in cols)
        values.insert(X(i), gtsam.Pose2(x, y, th))
    return values


def _staged(problem: GraphProblem) -> bool:
    """Odometry calibration with a robust odometry loss: solved in stages."""
    loss = problem.robust.get(problem.odometry_stream, ("none", 0.0))[0]
    return problem.odometry_calibration is not None and loss != "none"


def run_smoother(log, config, error_samples: int = 0) -> EstimateResult:
    """Batch Levenberg-Marquardt over the whole log (``estimator: smoother``).

    With odometry calibration *and* a robust odometry loss the calibration variables are
    kept out of the loss, in three stages: (1) the calibration is estimated with Gaussian
    odometry factors (every other stream keeps its loss); (2) it is held at that estimate,
    the odometry factors become built-in ``BetweenFactorPose2`` of the calibrated relative
    poses under the robust loss, and the trajectory is re-solved from stage 1's; (3) the
    robust weights of stage 2's odometry factors are frozen (each factor Gaussian with its
    covariance divided by its weight) and trajectory and calibration are solved together
    again, the calibration Jacobian exact. A robust weight that responds to the calibration
    inside a solve lets one shared variable turn *every* odometry factor into a down-weighted
    outlier at once (a cheap minimum of a log-growing or redescending loss), which is what
    drove keyframes tens of metres apart; frozen weights cannot, while stage 3 still removes
    stage 1's contamination by the outlier steps. ``extra["stages"]`` gives each stage's
    iterations and error and how many odometry factors stage 2 down-weighted below 0.5.
    A sensor stream with Tukey's loss is solved with Huber's first (:func:`_convex_start`;
    with odometry calibration, stage 1 is), except with loop closures or an incremental
    SLAM start.

    Parameters
    ----------
    log, config
        The log and the run config.
    error_samples : int
        Joint samples of the position errors to draw (0: none).

    Returns
    -------
    EstimateResult
        Keyframe poses with world-frame marginal covariances; ``used``/``rejected`` per
        stream; ``extra``: ``calibration`` (state -> value), ``landmarks`` (SLAM: id -> [x, y]),
        ``outliers`` (per stream, beyond the model's gate at the optimum), ``residuals``,
        ``keyframes``, ``iterations``, ``final_error``, ``solve_s``, ``variance_components``
        (:func:`~odofuse.estimators.graph.variance.variance_components` at the optimum: the
        cross-check's scale of these covariances; ``skipped: <reason>`` when its normal
        matrix cannot be factored), ``_error_samples`` (with ``error_samples`` K > 0, its K
        joint :class:`~odofuse.estimators.graph.variance.ErrorSamples`, in memory only: the
        cross-check's posterior, never written; only the cross-check's reference asks for
        them, so a smoother run of its own does not pay for them); ``findings`` for a solver
        that did not converge, covariances that could not be computed, and the checks of
        :mod:`odofuse.status.graph_checks`.
    """
    import gtsam

    problem = build_problem(log, config, "smoother")
    opts = problem.options
    findings: list = []
    extra: dict = {}
    calibrated = bool(problem.calib) or problem.odometry_calibration is not None
    incremental = opts.slam and (
        opts.slam_init == "incremental" or (opts.slam_init == "auto" and not calibrated)
    )
    t0 = time.perf_counter()
    if _staged(problem):
        stage1 = functools.partial(Factors, odometry_robust=False)
        # stage 1 starts from the EKF's poses, and from their Huber optimum when a sensor has
        # Tukey's loss
        start = (
            None
            if incremental or problem.loops
            else _convex_start(problem, opts, stage1, filter_start(problem, log, config))
        )
        fac1, graph, values = build_graph(problem, stage1(problem), start)
        if incremental:
            values, init = incremental_initial_values(problem, values)
            extra.update(init)
        first = _solve(graph, values, fac1, opts)
        findings += solver_findings("stage 1 (calibration)", first.reason, first.iterations)
        p_hat = np.asarray(first.values.atVector(problem.odometry_key), dtype=float)
        fac2, graph, values = build_graph(
            problem, Factors(problem, odometry_fixed=p_hat), first.values
        )
        second = _solve(graph, values, fac2, opts)
        findings += solver_findings("stage 2 (robust odometry)", second.reason, second.iterations)
        weights = robust_weights([f for _, f in fac2.odometry_created], second.values)
        start = gtsam.Values(second.values)
        start.insert(problem.odometry_key, p_hat)
        fac, graph, values = build_graph(problem, Factors(problem, odometry_weights=weights), start)
        out = _solve(graph, values, fac, opts)
        result = out.values
        extra["stages"] = {
            "iterations": [int(first.iterations), int(second.iterations), int(out.iterations)],
            "final_error": [float(first.error), float(second.error), float(out.error)],
            "odometry_downweighted": int(np.count_nonzero(weights < 0.5)),
        }
    else:
        start = (
            None
            if incremental or problem.loops
            else _convex_start(problem, opts, initial=filter_start(problem, log, config))
        )
        fac, graph, values = build_graph(problem, None, start)
        if incremental:
            values, init = incremental_initial_values(problem, values)
            extra.update(init)
        if problem.loops:  # the chordal poses where they beat dead reckoning or the pass
            values, extra["initial"] = loop_initial_values(problem, graph, values)
        out = _solve(graph, values, fac, opts)
        result = out.values
    findings += solver_findings("Levenberg-Marquardt", out.reason, out.iterations)
    solve_s = time.perf_counter() - t0
    covs = None
    # one linearisation at the optimum for the marginals and the variance components
    lin = graph.linearize(result) if opts.covariances else None
    if opts.covariances:
        keys = [X(i) for i in range(len(problem.kt))]
        keys += calibration_keys(problem, result)
        landmark_keys = [key for key in fac.landmark_keys.values() if result.exists(key)]
        cov, bad = marginal_covariances(graph, result, keys + landmark_keys, fac.dims, lin)
        findings += bad
        if cov:
            poses = pose_array(out.values, len(problem.kt))
            covs = world_covs(problem, poses, cov.__getitem__)
            extra.update(calibration_sigmas(problem, result, cov.__getitem__))
            if opts.slam:
                extra["landmark_covariances"] = landmark_covariances(fac, result, cov.__getitem__)
    extra.update(
        {"iterations": int(out.iterations), "final_error": float(out.error), "solve_s": solve_s}
    )
    if opts.covariances and covs is not None:  # the scale of those covariances
        keys = [X(i) for i in range(len(problem.kt))]
        try:  # a normal matrix the sparse LU cannot factor: no scale, the run goes on
            system = WhitenedSystem(graph, result, lin)
            vc = variance_components(
                graph,
                result,
                factor_groups(fac, graph),
                keys,
                samples=error_samples,
                system=system,
            )
            if error_samples > 0:
                vc, extra["_error_samples"] = vc
            extra["variance_components"] = vc
            # the time-stamp test's score in this system (status.latency reads it)
            extra["_latency_scores"] = time_offset_scores(fac, graph, system, log, config, vc)
        except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
            extra["variance_components"] = {"skipped": one_line(exc)}
    return finish(problem, fac, result, covs, "smoother", extra, findings, graph=graph)
