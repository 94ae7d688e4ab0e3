"""Incremental graph solvers: iSAM2 with the calibration freeze, and the fixed-lag smoother.

Owns :func:`run_isam2` (one ``ISAM2.update`` per keyframe, its latency figures, the
``calibration_freeze`` of converged sensor and odometry calibration states, and the final
batch LM pass that makes its result the optimum of iSAM2's own graph) and
:func:`run_fixed_lag`
(GTSAM's ``IncrementalFixedLagSmoother``, each keyframe's pose taken just before it leaves
the window), with the iSAM2 parameters both use.
"""

from __future__ import annotations

import bisect
import functools
import time

import numpy as np

from odofuse import se2
from odofuse.errors import ConfigError
from odofuse.estimators.graph import innovations, solvers
from odofuse.estimators.graph.factors import Factors
from odofuse.estimators.graph.isam2_slam import cholesky_suits, incremental_slam
from odofuse.estimators.graph.isam2_window import KeyframeWindow
from odofuse.estimators.graph.keys import X, is_vector, model_kind
from odofuse.estimators.graph.marginals import optimum_marginals
from odofuse.estimators.graph.problem import GraphProblem, build_problem, convex_problem
from odofuse.estimators.graph.solvers import (
    calibration_sigmas,
    finish,
    landmark_covariances,
    polish_isam2,
    pose_array,
    world_covs,
)
from odofuse.status.findings import Finding
from odofuse.status.graph_checks import solver_findings
from odofuse.trajectory import EstimateResult


def _latency_summary(lat) -> dict:
    lat = np.asarray(lat) * 1e3
    if lat.size == 0:
        return {}
    quarters = np.array_split(lat, 4) if lat.size >= 4 else [lat]
    return {
        "median_ms": float(np.median(lat)),
        "p99_ms": float(np.percentile(lat, 99)),
        "max_ms": float(lat.max()),
        "updates": int(lat.size),
        # how latency grows with the log: median and p99 of each quarter of the updates
        "quarters_median_ms": [float(np.median(q)) for q in quarters],
        "quarters_p99_ms": [float(np.percentile(q, 99)) for q in quarters],
    }


def _failure(solver: str, problem: GraphProblem, i: int, exc: Exception) -> Finding:
    detail = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:160]
    return Finding(
        "solver",
        f"{solver} update failed at keyframe {i} ({detail}); the keyframes from there on are "
        "dead-reckoned from the last estimate and no covariances are given",
        t_start=float(problem.kt[i]),
        t_end=float(problem.kt[-1]),
        figure=float(i),
    )


def _dead_reckoned_from(problem: GraphProblem, poses: np.ndarray, i: int) -> None:
    """Fill ``poses[i:]`` by composing the odometry from ``poses[i - 1]`` (in place)."""
    if i == 0:
        poses[0] = problem.pose0
    for j in range(max(i, 1), len(problem.kt)):
        poses[j] = se2.compose(poses[j - 1], problem.deltas[j - 1])
    poses[:, 2] = se2.wrap(poses[:, 2])


def _with_poses(est, poses: np.ndarray, keys):
    """``gtsam.Values`` holding ``poses`` as ``X(i)`` and ``keys`` (calibration vectors,
    landmark points) copied from ``est`` where it has them."""
    import gtsam

    out = gtsam.Values()
    for key in keys:
        if gtsam.Symbol(key).chr() != ord("x") and est.exists(key):
            # calibration vectors (c<n>, o0) and landmark / beacon points (l<id>, b<n>)
            out.insert(key, est.atVector(key) if is_vector(key) else est.atPoint2(key))
    for i in range(len(poses)):
        out.insert(X(i), gtsam.Pose2(*poses[i]))
    return out


# The clock of the latency figures (wall time). benchmarks/bench_graph.py sets it to
# ``time.thread_time`` (GTSAM runs single-threaded) so that a shared machine's load does not
# enter its per-quarter ratios.
_clock = time.perf_counter


def _newest_estimate(isam, key: int, guess):
    """iSAM2's estimate of the pose ``key`` added by the last update, at the cost of one clique.

    ``calculateEstimatePose2`` first brings iSAM2's whole delta up to date (the wildfire
    back-substitution from the root, which keeps reaching every clique while a global
    calibration variable at the root moves), so calling it once per keyframe costs O(n) per
    step. A variable added by the last update still has its initial guess as linearisation
    point (iSAM2 relinearises only variables whose delta it has computed before), and the mean
    of its marginal (``marginalFactor``: the root clique, where iSAM2 orders the keys of new
    factors) is its Gauss-Newton step, so ``guess.retract(step)`` is the same estimate (equal
    to 1e-9 m / rad on Plaza1; tests/test_graph.py).

    Parameters
    ----------
    isam : gtsam.ISAM2
        Right after the update that added ``key``.
    key : int
        The new pose's key.
    guess : gtsam.Pose2
        The initial value given for ``key`` in that update (world frame, m / rad).

    Returns
    -------
    gtsam.Pose2
        The estimate of ``key`` (world frame).
    """
    import gtsam

    step = isam.marginalFactor(key).solve(gtsam.VectorValues()).at(key)
    return guess.retract(step)


class _PrivateBeaconFactors(Factors):
    """:class:`Factors` whose ranges to a known beacon without range calibration go to a
    private pinned copy of the beacon (``b<n>``), as the frozen ranges already do.

    A shared pinned ``l<id>`` is at the root of iSAM2's Bayes tree (every new range involves
    it), and each update gathers *all* the factors on it (``ISAM2::relinearizeAffectedFactors``
    builds the set of every factor touching an affected key), so each relinearisation step
    grows with the number of ranges so far. With a copy per range each factor stays local.
    The model is the same (the beacon is pinned either way, ``known_landmark_sigma``), and
    the final LM pass solves the graph with the copies. Plaza1 without calibration: p99
    update 4.8x -> 1.7x from the first to the last quarter (docs/graph.md).
    """

    def measurement(self, meas, loss=None):
        m = self.p.models[meas.stream]
        if (
            model_kind(m) == "BeaconRange"
            and meas.landmark in self.landmark_keys
            and not self.model_calib(m)
        ):
            if loss is not None:  # a twin: with_loss clones the built-in factor (same copy)
                raise ValueError("a private beacon range's twin is a clone (Factors.with_loss)")
            loss, k = self.p.robust.get(meas.stream, ("none", 0.0))
            return self._frozen_beacon_range(m, meas, loss, k)
        return super().measurement(meas, loss)


def _polish(graph, values, fac, options):
    """:func:`~odofuse.estimators.graph.solvers.polish_isam2` with what a run reports of it
    (``graph`` / ``values``: iSAM2's whole final graph and its estimate).

    Returns ``(values, extra, findings)``: the optimum of iSAM2's own final graph,
    ``{"final_iterations", "final_gauss_newton", "final_error", "final_s"}`` and the
    ``solver`` findings of the final LM (its iteration cap, no decrease).
    """
    t0 = time.perf_counter()
    out = polish_isam2(graph, values, fac, options)
    extra = {
        "final_iterations": int(out.iterations),
        "final_gauss_newton": int(out.gauss_newton),  # steps after the LM (polish_isam2)
        "final_error": float(out.error),
        "final_s": time.perf_counter() - t0,
    }
    return (
        out.values,
        extra,
        solver_findings("final Levenberg-Marquardt", out.reason, out.iterations),
    )


#: iSAM2 SLAM relinearises its unknown landmarks at this fraction of ``relinearize_threshold``
#: (1 cm at the default 0.1). At 0.1 m a landmark seen at 5 cm sigma kept a linearisation up
#: to two sigmas stale, and the predicted sightings (``innovations``) were overconfident:
#: ``benchmarks/bench_slam_status.py``'s nominal logs said ``degraded`` on 10 of 100 seeds
#: (NIS windows and run above their band), against 0.2 % that the checks state; with landmarks
#: at a tenth, 0 (docs/graph.md, "iSAM2 SLAM tests its landmark re-sightings").
SLAM_LANDMARK_RELINEARIZE = 0.1


def _threshold_map(problem: GraphProblem, special: dict, default: float):
    """GTSAM's per-key-type relinearisation thresholds: ``special`` (key type -> threshold),
    ``default`` for every other type of odofuse's keys (GTSAM needs an entry for each)."""
    import gtsam

    oc = problem.odometry_calibration
    thresholds = gtsam.ISAM2ThresholdMap()
    for kind, dim in (
        ("x", 3),
        ("l", 2),
        ("b", 2),
        ("c", 1),
        ("w", 1),  # a walking gyro bias's later segments, calibration like c<n>
        ("o", len(oc.nominal) if oc is not None else 1),
    ):
        thresholds.insert((kind, np.full(dim, special.get(kind, default))))
    return thresholds


def _isam2_params(problem: GraphProblem, factorization: str = "QR", partial: bool = False):
    """iSAM2 parameters. Relinearisation is kept coarse (0.1 m / rad every 10 updates by
    default) because a calibration variable touches every range factor: relinearising it
    re-runs all their Python callbacks; with ``slam`` the unknown landmarks take a finer
    threshold (:data:`SLAM_LANDMARK_RELINEARIZE`). ``factorization`` QR by default: pinned landmarks
    (sigma 1e-6 m) and 0.1 mm odometry floors make the normal equations too ill-conditioned
    for iSAM2's Cholesky (``"CHOLESKY"`` where
    :func:`~odofuse.estimators.graph.isam2_slam.cholesky_suits` says it may be tried).
    ``partial``: GTSAM's ``enablePartialRelinearizationCheck`` (only the branches an update
    touched are checked), the iSAM2 estimator's default (``partial_relinearization_check``),
    whose result is the polished optimum of its final graph: on ``w20000.txt`` the run takes
    130 s instead of 196 s and ends at the same graph error (18.763351). The fixed-lag
    smoother keeps the full check: its online estimates are its output."""
    import gtsam

    options = problem.options
    params = gtsam.ISAM2Params()
    r = options.relinearize_threshold
    if options.slam:  # unknown landmarks at a tenth of it (SLAM_LANDMARK_RELINEARIZE)
        l_r = r * SLAM_LANDMARK_RELINEARIZE
        params.setRelinearizeThreshold(_threshold_map(problem, {"l": l_r}, r))
    else:
        params.setRelinearizeThreshold(r)
    params.relinearizeSkip = options.relinearize_skip
    params.enablePartialRelinearizationCheck = partial
    params.setFactorization(factorization)
    return params


def _freeze_groups(problem: GraphProblem, fac: Factors, source: str) -> dict[str, tuple[str, ...]]:
    """Stream -> calibration states that ``calibration_freeze`` freezes together.

    A sensor's later factors can use constants only when *all* its calibration states are
    frozen, so each stream with calibration states forms one group. Only unary sensor
    factors can be frozen (the gyro's heading-increment factor is not). With absolute
    thresholds every group must have a threshold for each of its states and naming a gyro
    state is an error; with the convergence form every freezable sensor forms a group and a
    gyro's states simply stay estimated.
    """
    spec = problem.options.calibration_freeze
    if not spec:
        return {}
    oc = problem.odometry_calibration
    odometry = {problem.odometry_stream: tuple(oc.names)} if oc is not None else {}
    if "rel_change" in spec:
        return {
            **{
                stream: tuple(fac.model_calib(m))
                for stream, m in problem.models.items()
                if fac.model_calib(m) and model_kind(m) != "GyroYawRate"
            },
            **odometry,
        }
    key = "options.isam2.calibration_freeze.sigma"
    known = set(problem.calib) | {n for names in odometry.values() for n in names}
    bad = sorted(set(spec["sigma"]) - known)
    if bad:
        raise ConfigError(
            f"'{bad[0]}' is not an estimated calibration state "
            f"(estimated: {', '.join(sorted(known)) or 'none'})",
            source,
            f"{key}.{bad[0]}",
        )
    groups: dict[str, tuple[str, ...]] = {}
    for stream, m in problem.models.items():
        states = tuple(fac.model_calib(m))
        if not states or not set(states) & set(spec["sigma"]):
            continue
        if model_kind(m) == "GyroYawRate":
            raise ConfigError(
                "the gyro's heading-increment factor cannot be frozen (unary sensors only)",
                source,
                f"{key}.{next(s for s in states if s in spec['sigma'])}",
            )
        missing = [s for s in states if s not in spec["sigma"]]
        if missing:
            raise ConfigError(
                f"sensor '{stream}' estimates {', '.join(states)}: give a threshold for each",
                source,
                f"{key}.{missing[0]}",
            )
        groups[stream] = states
    for stream, states in odometry.items():
        if set(states) & set(spec["sigma"]):
            missing = [s for s in states if s not in spec["sigma"]]
            if missing:
                raise ConfigError(
                    f"odometry calibration estimates {', '.join(states)}: give a threshold "
                    "for each",
                    source,
                    f"{key}.{missing[0]}",
                )
            groups[stream] = states
    return groups


def _converged(history: list, t: float, n: int, sig: dict, spec: dict) -> tuple[bool, dict]:
    """The convergence test of ``calibration_freeze: {rel_change, window}`` for one sensor.

    Parameters
    ----------
    history : list of (t [s], n factors, {state: sigma})
        Earlier checks of this sensor, in time order.
    t : float
        s, log time of this check; ``n`` the sensor's factor count so far; ``sig`` the
        current marginal sigma of each of its calibration states.
    spec : dict
        The parsed option (``rel_change``, ``window`` [s]).

    Returns
    -------
    (bool, dict)
        Whether every sigma shrank by less than ``rel_change`` (relative) since the last check
        at least ``window`` s ago, with at least one new factor of the sensor since then; and
        the sigmas of that earlier check (empty if there is none yet).
    """
    times = [h[0] for h in history]
    j = bisect.bisect_right(times, t - spec["window"]) - 1
    if j < 0:
        return False, {}
    _, n_then, sig_then = history[j]
    if n <= n_then:  # no new measurement: no evidence that the information stopped growing
        return False, sig_then
    ok = all(sig_then[s] - sig[s] < spec["rel_change"] * sig_then[s] for s in sig)
    return ok, sig_then


def run_isam2(log, config) -> EstimateResult:
    """iSAM2, one update per keyframe in time order (``estimator: isam2``).

    The trajectory is the optimum of iSAM2's final graph: after ``final_relinearizations``
    forced relinearising updates, batch LM from iSAM2's estimate
    (:func:`~odofuse.estimators.graph.solvers.polish_isam2`, as on the SLAM path;
    ``extra["final_iterations"]``, ``final_gauss_newton``, ``final_error``, ``final_s``, and a
    ``solver`` finding if it stops at ``max_iterations``), with the covariances of that
    optimum (:func:`~odofuse.estimators.graph.marginals.optimum_marginals`). iSAM2 itself
    relinearises a variable only once its update exceeds ``relinearize_threshold``, so its
    own last estimate is that of a graph linearised at stale points (on Plaza2 0.257 m
    against 0.232 m at the optimum of the same graph). ``extra["latency"]`` summarises the
    wall time of each ``ISAM2.update`` and ``extra["latency_step"]`` that of the whole
    per-keyframe step (factor creation, update, freeze check, current-pose estimate), median /
    p99 / max and per quarter of the log, ms. Keyframes older than the last
    :data:`~odofuse.estimators.graph.isam2_window.KEEP` leave iSAM2's tree online in batches
    (:class:`~odofuse.estimators.graph.isam2_window.KeyframeWindow`, bounded update cost;
    ``extra["marginalised_keyframes"]``), unless a loop closure reaches further back than that
    (then every keyframe stays); the final pass still solves the whole graph.
    A stream with Tukey's loss (the default gate loss of an absolute sensor) is updated
    online with Huber's at the same threshold, and the final pass solves the same factors
    with Tukey's from there, as the smoother does
    (:func:`~odofuse.estimators.graph.problem.convex_problem`): with Tukey's online, a
    prediction that drifted past the threshold (an outage) ignored the returning readings
    for good (4.1 m RMSE after a 120 s GPS outage in simulation, the smoother 0.31 m).

    Calibration freezing (``options.isam2.calibration_freeze``): a calibration variable
    (e.g. range scale/offset) is connected to every factor of its sensor, so each update
    touches it and iSAM2's cost grows with the number of those factors. Every
    ``check_every`` updates the marginal sigma of each calibration state is read from the
    Bayes tree; once all the states of a sensor are below their thresholds (``sigma`` form)
    or have converged (``rel_change`` form: each sigma shrank by less than ``rel_change``
    over the last ``window`` s of log time, the sensor got new factors in that window and
    ``min_time`` s have elapsed), that sensor's later factors hold the current estimate as constants
    (:func:`~odofuse.estimators.graph.custom_factors.frozen_calibration_factor`) and no longer
    involve the variable. The
    variable stays in the graph, still estimated from the factors added before the freeze;
    what is given up is the information of the later measurements about the calibration
    (and its correlation with the later poses). The odometry calibration vector
    (``odometry_calibration``) is one more group: once frozen, later odometry factors are
    built-in ``BetweenFactorPose2`` of the calibrated relative poses instead of Python
    calibrated between factors. ``extra["calibration_freeze"]`` gives, per
    frozen state, the constant, its sigma, the keyframe index and time of the freeze (and,
    for the ``rel_change`` form, ``sigma_window_ago``: its sigma one window earlier).

    iSAM2 factorises by Cholesky where
    :func:`~odofuse.estimators.graph.isam2_slam.cholesky_suits` allows it (a pose graph of
    poses and unknown landmarks); a run that meets an indeterminate system there is run again
    with QR, the factorisation of every other run.
    """
    problem = build_problem(log, config, "isam2")
    if cholesky_suits(problem):
        try:
            return _run_isam2(problem, config, "CHOLESKY")
        except _CholeskyFailed:  # the whole run again with QR, on a fresh problem
            problem = build_problem(log, config, "isam2")
    return _run_isam2(problem, config, "QR")


class _CholeskyFailed(Exception):
    """An iSAM2 run with Cholesky met an indeterminate system (``run_isam2`` retries with QR)."""


def _run_isam2(problem: GraphProblem, config, factorization: str) -> EstimateResult:
    """:func:`run_isam2` of a built ``problem`` with iSAM2's ``factorization``; with
    ``"CHOLESKY"`` a failed update raises :class:`_CholeskyFailed` instead of a finding."""
    import gtsam

    cholesky = factorization == "CHOLESKY"
    partial = problem.options.partial_relinearization_check
    if problem.options.slam:  # unknown landmarks: odofuse.estimators.graph.isam2_slam
        params = _isam2_params(problem, factorization, partial)
        source = getattr(config, "source", "<config>")
        monitor = innovations.monitor(problem)  # the NIS checks of the localisation path
        try:
            isam, fac, window, lat = incremental_slam(problem, params, source, monitor)
            # with the configured losses (fac.final) when iSAM2 had convex ones online
            final_graph = window.graph if fac.final is None else fac.final
            optimum, polished, bad = _polish(
                final_graph, window.estimate(isam), fac, problem.options
            )
            extra = {
                "latency": _latency_summary(lat[0]),
                "latency_step": _latency_summary(lat[1]),
                "marginalised_keyframes": window.marginalised,  # left iSAM2's tree online
                "nis": innovations.summary(monitor),
                **polished,
            }
            bad = list(bad) + innovations.findings(monitor, problem)
            return _slam_result(problem, params, fac, extra, bad, final_graph, optimum)
        except RuntimeError as exc:
            if cholesky:
                raise _CholeskyFailed from exc
            raise
    # A stream with Tukey's loss is updated online with Huber's at the same threshold (a
    # prediction that drifted past it, e.g. after an outage, would otherwise ignore the
    # readings that correct it for good); the final pass solves the graph with Tukey's from
    # there, as the smoother does (problem.convex_problem)
    soft = convex_problem(problem)
    fac = _PrivateBeaconFactors(
        soft or problem, final_robust=None if soft is None else problem.robust
    )
    groups = _freeze_groups(problem, fac, getattr(config, "source", "<config>"))
    spec = problem.options.calibration_freeze or {}
    params = _isam2_params(problem, factorization, partial)
    isam = gtsam.ISAM2(params)
    graph, values = fac.static()
    # Calibration states touch every factor of their sensor: relinearising them online would
    # re-run all those (Python) factors, so they are relinearised only in the final passes
    # (range and gyro models are linear in them anyway).
    frozen = gtsam.KeyList()
    for key, _, _ in problem.calib.values():
        frozen.push_back(key)
    if problem.odometry_calibration is not None:
        frozen.push_back(problem.odometry_key)
    latency, step = [], []
    freeze_info: dict[str, dict] = {}
    frozen_streams: set[str] = set()
    history: dict[str, list] = {stream: [] for stream in groups}
    n_factors: dict[str, int] = {}
    oc_index = {n: j for j, n in enumerate(getattr(problem.odometry_calibration, "names", ()))}

    def state_key(s):  # (key, component) of a sensor or odometry calibration state
        return (problem.odometry_key, oc_index[s]) if s in oc_index else (problem.calib[s][0], 0)

    def state_sigma(s) -> float:
        key, j = state_key(s)
        return float(np.sqrt(isam.marginalCovariance(key)[j, j]))

    def state_value(s) -> float:
        key, j = state_key(s)
        return float(isam.calculateEstimateVector(key)[j])

    window = KeyframeWindow()
    # a loop closure is added with its later keyframe: if its earlier one could have left
    # the tree by then, every keyframe stays (no window; KeyframeWindow.loops_reach_back)
    window.hold = 0 if KeyframeWindow.loops_reach_back(problem.loops) else None
    current = gtsam.Pose2(*problem.pose0)
    online = np.empty((len(problem.kt), 3))  # each keyframe's estimate right after its update
    findings: list[Finding] = []
    monitor = innovations.monitor(problem)  # the filters' NIS checks, as fixed-lag's
    newest: dict = {}  # the pose the last update added -> its estimate, read after it
    for i in range(len(problem.kt)):
        t_step = _clock()
        if i > 0:
            current = current.compose(gtsam.Pose2(*problem.deltas[i - 1]))
        g, v = fac.keyframe(i, current)
        if i > 0 and fac.rows:
            read = functools.partial(innovations.current_values, known=newest)
            innovations.observe(monitor, isam, fac, g, v, read)
        graph.push_back(g)
        values.insert(v)
        window.add(graph, values)
        t0 = _clock()
        try:
            window.update(isam, i, graph, values, frozen)  # old keyframes may leave
            latency.append(_clock() - t0)
            if i > 0:  # the root clique's marginal can be indeterminate too (a diverged run)
                current = _newest_estimate(isam, X(i), current)
                newest = {X(i): current}
        except RuntimeError as exc:  # indeterminate system: report, never a traceback
            if cholesky:
                raise _CholeskyFailed from exc
            findings.append(_failure("iSAM2", problem, i, exc))
            break
        for meas in fac.by_kf.get(i, ()):
            n_factors[meas.stream] = n_factors.get(meas.stream, 0) + 1
        n_factors[problem.odometry_stream] = i  # odometry factors so far
        if groups and i % spec["check_every"] == 0:
            t_i = float(problem.kt[i])
            for stream in [s for s in groups if s not in frozen_streams]:
                sig = {s: state_sigma(s) for s in groups[stream]}
                before: dict = {}
                if "sigma" in spec:
                    ok = all(sig[s] < spec["sigma"][s] for s in groups[stream])
                else:
                    n = n_factors.get(stream, 0)
                    ok, before = _converged(history[stream], t_i, n, sig, spec)
                    ok = ok and t_i - float(problem.kt[0]) >= spec["min_time"]
                    history[stream].append((t_i, n, sig))
                if ok:
                    for s in groups[stream]:
                        value = state_value(s)
                        fac.frozen[s] = value
                        freeze_info[s] = {
                            "value": value,
                            "sigma": sig[s],
                            "keyframe": i,
                            "t": t_i,
                        }
                        if before:
                            freeze_info[s]["sigma_window_ago"] = before[s]
                    frozen_streams.add(stream)
                    if stream == problem.odometry_stream:  # later odometry: built-in factors
                        names = problem.odometry_calibration.names
                        fac.odometry_fixed = np.array([fac.frozen[s] for s in names])
        online[i] = (current.x(), current.y(), current.theta())
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        step.append(_clock() - t_step)
    covs = None
    extra = {"latency": _latency_summary(latency), "latency_step": _latency_summary(step)}
    extra["marginalised_keyframes"] = window.marginalised  # left iSAM2's tree (isam2_window)
    solved = None  # the graph ``result`` is the optimum of (solvers.on_solution)
    if not findings:
        try:
            for _ in range(problem.options.final_relinearizations):
                isam.update(force_relinearize=True)
            # iSAM2's estimate solves a graph linearised at stale points (each variable is
            # relinearised only once its update exceeds relinearize_threshold): the offline
            # result is the optimum of iSAM2's own final graph, batch LM from its estimate
            # (with the configured losses: fac.final, when iSAM2 had convex ones online)
            final_graph = window.graph if fac.final is None else fac.final
            result, polished, bad = _polish(
                final_graph, window.estimate(isam), fac, problem.options
            )
            extra.update(polished)
            findings.extend(bad)
            if problem.options.covariances:
                cov_of = optimum_marginals(final_graph, result, params)
                covs = world_covs(problem, pose_array(result, len(problem.kt)), cov_of)
                extra.update(calibration_sigmas(problem, result, cov_of))
            solved = final_graph
        except RuntimeError as exc:
            if cholesky:
                raise _CholeskyFailed from exc
            findings.append(_failure("iSAM2 (final relinearisation)", problem, len(online), exc))
            covs, result = None, _with_poses(window.estimate(isam), online, fac.dims)
    else:
        failed = int(findings[-1].figure)
        _dead_reckoned_from(problem, online, failed)
        result = _with_poses(window.estimate(isam), online, fac.dims)
    if groups:
        extra["calibration_freeze"] = freeze_info
    extra["nis"] = innovations.summary(monitor)
    findings += innovations.findings(monitor, problem)
    return finish(problem, fac, result, covs, "isam2", extra, findings, graph=solved)


def _slam_result(problem, params, fac, extra, findings, graph, result) -> EstimateResult:
    """The final iSAM2 SLAM estimate: ``result``, the optimum of ``graph`` (the polish's), with
    the pose and landmark covariances there (:func:`~odofuse.estimators.graph.marginals.
    optimum_marginals`, ``params`` the run's iSAM2 parameters for its fallback).

    Not ``isam.calculateEstimate()``: that is one undamped Gauss-Newton step beyond the
    linearisation point, nothing where the polish converged, but after a polish that stopped
    short (``bench_slam_status.py --real-wheels``, seed 2019, before the LM's lambda bound
    was raised) a step to graph error 4,281.7 from the optimum's 2,516.3, reported with the
    latter as ``final_error``."""
    covs = None
    if problem.options.covariances:
        cov_of = optimum_marginals(graph, result, params)
        covs = world_covs(problem, pose_array(result, len(problem.kt)), cov_of)
        extra["landmark_covariances"] = landmark_covariances(fac, result, cov_of)
        extra.update(calibration_sigmas(problem, result, cov_of))
    return finish(problem, fac, result, covs, "isam2", extra, findings, graph=graph)


def _fixed_lag_params(problem: GraphProblem):
    """iSAM2 parameters of the fixed-lag smoother: :func:`_isam2_params`, but the calibration
    vectors (sensor states ``c<n>`` and a walking bias's segments ``w``, the odometry
    calibration ``o0``) are relinearised at
    every relinearisation check in which they moved at all.

    With the common ``relinearize_threshold`` (0.1) a calibration state that converges by less
    than 0.1 from its prior (Plaza1's range scale: 1.0 -> 1.071) is never relinearised, so
    every range factor is linearised, and its robust (Huber) weight computed, at scale 1.0:
    a 30 m range then looks 2 m off and is down-weighted, so the reported marginals count
    the ranges at the weights of a wrong scale while the estimate (linear in the scale) uses
    the right one. Measured on Plaza1 with ``plaza1-fixed_lag.yaml``: position NEES 0.68 ->
    1.21 (the batch smoother with the same noise: 1.60), RMSE 0.212 -> 0.206 m. Only the
    window's factors touch a calibration vector (marginalised ones become one linear factor),
    so a check costs what the window holds: unchanged at ``lag`` 10 or 100 s, 1.7x the CPU
    time at 300 s (docs/graph.md); iSAM2 (:func:`run_isam2`) has no such bound.

    Parameters
    ----------
    problem : GraphProblem
        Supplies the options and the odometry calibration's dimension.

    Returns
    -------
    gtsam.ISAM2Params
        With a per-variable-type threshold map: ``relinearize_threshold`` for poses
        (``x``) and points (``l``, ``b``), 0 for ``c``, ``w`` and ``o``.
    """
    params = _isam2_params(problem)
    r = problem.options.relinearize_threshold
    params.setRelinearizeThreshold(_threshold_map(problem, {"c": 0.0, "w": 0.0, "o": 0.0}, r))
    return params


def run_fixed_lag(log, config) -> EstimateResult:
    """GTSAM ``IncrementalFixedLagSmoother`` with a ``lag``-second window (``fixed_lag``).

    Each keyframe's pose (and world-frame covariance) is the one held just before it leaves
    the window, i.e. smoothed with ``lag`` seconds of future data; memory is bounded by the
    window. Calibration and landmark variables are kept in the window, so each covariance is
    the marginal of the window's joint (the calibration's uncertainty included), taken with
    the estimate; the calibration vectors are relinearised at every check
    (:func:`_fixed_lag_params`) so that it is the marginal at that estimate. Keyframes still
    in the window at the end get the final estimate (less than ``lag`` s of future data).
    A stream with Tukey's loss (the default gate loss) gets the filters' gate instead: each
    row whose NIS against the window's prediction (:mod:`~odofuse.estimators.graph.
    innovations`) is beyond the stream's gate is left out of the graph and counted in
    ``rejected``; from the ``reject_run``-th consecutive one on, the stream's rows go in until
    one is within the gate again, as a filter re-opens
    (:func:`~odofuse.estimators.graph.innovations.gated_out`); the rows that go in have Huber's
    loss at Tukey's threshold
    (:func:`~odofuse.estimators.graph.problem.convex_problem`). Tukey's would ignore the
    returning readings for good once a prediction drifted past its threshold, and there is no
    final pass to solve with it from a convex start; Huber's alone gave a gross GNSS fix a
    bounded but lasting pull: ``ok`` over Sokal's 99.9 % NEES bound on 5 of 40 real-robot
    logs (``bench_status.py --real-robot --first 8400 --seeds 40``), within it on all of
    them without their gross fixes (docs/trust.md). A row left out is still evaluated against
    the final estimate in ``residuals`` and ``outliers``, as the smoother's rows beyond
    Tukey's threshold are.
    """
    import gtsam

    problem = build_problem(log, config, "fixed_lag")
    soft = convex_problem(problem)  # Huber where Tukey is configured
    fac = Factors(soft or problem)
    lag = problem.options.lag
    params = _fixed_lag_params(problem)
    smoother = gtsam.IncrementalFixedLagSmoother(lag, params)
    graph, values = fac.static()
    walking = set(fac.bias_current.values())  # stamped while current, then marginalised
    persistent = [k for k in values.keys() if k != X(0) and k not in walking]
    K = len(problem.kt)
    poses = np.empty((K, 3))
    covs = np.empty((K, 3, 3)) if problem.options.covariances else None
    done = 0  # keyframes [0, done) are final
    latency = []
    findings: list[Finding] = []
    current = gtsam.Pose2(*problem.pose0)
    monitor = innovations.monitor(problem)
    # the gated streams (Tukey's loss configured, Huber's given) -> their current run of
    # consecutive rejections (innovations.gated_out)
    runs = {s: 0 for s in (soft.robust if soft else ()) if soft.robust[s] != problem.robust[s]}
    # every factor given to the smoother, kept only for a benchmark's solvers.on_solution
    given = gtsam.NonlinearFactorGraph() if solvers.on_solution is not None else None

    def freeze(upto: int) -> None:
        nonlocal done
        while done < upto:
            p = smoother.calculateEstimatePose2(X(done))
            poses[done] = (p.x(), p.y(), p.theta())
            if covs is not None:
                covs[done] = se2.cov_body_to_world(
                    poses[done], smoother.marginalCovariance(X(done))
                )
            done += 1

    for i in range(K):
        t = float(problem.kt[i])
        if i > 0:
            current = current.compose(gtsam.Pose2(*problem.deltas[i - 1]))
        # keyframes that this update will marginalise: take their final estimate first
        freeze(int(np.searchsorted(problem.kt, t - lag, side="left")) if i > 0 else 0)
        g, v = fac.keyframe(i, current)
        if i > 0 and fac.rows:
            verdicts = innovations.observe(monitor, smoother.getISAM2(), fac, g, v)
            out = innovations.gated_out(verdicts, runs, monitor.options.reject_run)
            if out:
                g, out = innovations.without(g, out, v)
                for pos, meas, _ in verdicts:
                    if pos in out:
                        fac.used[meas.stream] -= meas.rows
                        problem.rejected[meas.stream] = (
                            problem.rejected.get(meas.stream, 0) + meas.rows
                        )
        graph.push_back(g)
        values.insert(v)
        if given is not None:
            given.push_back(graph)
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        stamps.insert((X(i), t))
        for key in (*persistent, *fac.bias_current.values()):
            stamps.insert((key, t))
        t0 = time.perf_counter()
        try:
            smoother.update(graph, values, stamps)
        except RuntimeError as exc:  # indeterminate system: report, never a traceback
            findings.append(_failure("fixed-lag smoother", problem, i, exc))
            break
        latency.append(time.perf_counter() - t0)
        current = smoother.calculateEstimatePose2(X(i))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    if findings:
        # the keyframes still in the window keep their last estimate, the rest dead-reckoned
        est = smoother.calculateEstimate()
        for j in range(done, int(findings[-1].figure)):
            p = est.atPose2(X(j))
            poses[j] = (p.x(), p.y(), p.theta())
        _dead_reckoned_from(problem, poses, int(findings[-1].figure))
        covs = None
    else:
        freeze(K)
    poses[:, 2] = se2.wrap(poses[:, 2])
    final_keys = [*persistent, *fac.bias_current.values()]
    final_values = _with_poses(smoother.calculateEstimate(), poses, final_keys)
    extra = {
        "latency": _latency_summary(latency),
        "lag_s": lag,
        "nis": innovations.summary(monitor),
    }
    if covs is not None:  # the calibration states stay in the window to the end
        extra.update(calibration_sigmas(problem, final_values, smoother.marginalCovariance))
    findings += innovations.findings(monitor, problem)
    given = given if covs is not None else None  # a failed run has no model to judge
    return finish(
        problem, fac, final_values, covs, "fixed_lag", extra, findings, stitched=True, graph=given
    )
