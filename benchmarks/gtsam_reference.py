"""GTSAM's own solutions of the planar datasets of its wheel: the references odofuse is judged by.

Used by ``benchmarks/bench_datasets.py`` and ``tests/test_graph_datasets.py``. Everything here
is plain GTSAM (``gtsam.load2D`` / ``gtsam.readG2o``, ``LevenbergMarquardtOptimizer``,
``ISAM2``), written from GTSAM's documented Python API, not from odofuse:

* :func:`load` reads a file with GTSAM's reader and adds a prior on the first pose (the
  readers add none, so the graph is gauge free).
* :func:`lm_optimum` is GTSAM's batch LM from the reader's initial values (:func:`lm_solve`
  also returns its iteration count).
* :func:`converged_optimum` is GTSAM's LM iterated with its tolerances at 0 until an
  iteration no longer lowers the error, then GTSAM's Gauss-Newton (QR) while it lowers it:
  the reference where ``LevenbergMarquardtOptimizer.optimize()`` with its defaults stops
  short (``w20000.txt``), started from :func:`chordal_start` (a complex-number chordal
  relaxation of the ``BetweenFactorPose2`` measurements, written here independently of
  odofuse's ``graph.chordal``).
* :func:`isam2_incremental` is the incremental solve of GTSAM's iSAM2 examples: poses in
  order, each new pose initialised by composing the odometry onto the current estimate, each
  new landmark from its first bearing-range sighting off the current pose estimate, one
  ``ISAM2.update`` per pose.
* :func:`solution_error` evaluates odofuse's solution in GTSAM's graph (``graph.error``) by
  mapping pose times and landmark ids back to GTSAM's keys.
"""

from __future__ import annotations

import math
import os

import numpy as np

#: Sigmas of the prior added on the first pose (x, y m; theta rad): odofuse's default
#: ``initial.sigma`` (odofuse.estimators.common.DEFAULT_INITIAL_SIGMA).
PRIOR_SIGMAS = (0.1, 0.1, 0.05)


def load(path, reader: str = "load2D"):
    """GTSAM's graph and initial values of ``path``, with a prior on the first pose.

    Returns
    -------
    graph, values, pose_keys
        ``pose_keys`` sorted (the odometry chain order of odofuse's loaders).
    """
    import gtsam

    if reader == "readG2o":
        graph, values = gtsam.readG2o(str(path), False)
    else:
        graph, values = gtsam.load2D(str(path))
    pose_keys = sorted(k for k in values.keys() if gtsam.Symbol(k).chr() == 0)
    if not pose_keys:  # victoria_park: no vertices; load2D composed the odometry
        pose_keys = sorted(k for k in values.keys() if gtsam.Symbol(k).chr() != ord("l"))
    first = pose_keys[0]
    start = values.atPose2(first)
    graph.add(gtsam.PriorFactorPose2(first, start, gtsam.noiseModel.Diagonal.Sigmas(PRIOR_SIGMAS)))
    return graph, values, pose_keys


def lm_optimum(graph, values, max_iterations: int = 100):
    """GTSAM's batch Levenberg-Marquardt from ``values`` (relative tolerance 1e-6)."""
    return lm_solve(graph, values, max_iterations)[0]


def lm_solve(graph, values, max_iterations: int = 100):
    """:func:`lm_optimum` and its iteration count: ``(values, iterations)``.

    ``iterations == max_iterations`` means GTSAM's LM stopped at its cap, not at a minimum
    (w20000: 100 iterations at error 523.3, still falling; docs/graph.md).
    """
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    return optimizer.optimize(), int(optimizer.iterations())


def chordal_start(graph, values, pose_keys):
    """``values`` with its poses from the chordal relaxation of the graph's ``BetweenFactorPose2``.

    Headings as complex numbers ``z`` (``z_j = z_i exp(i dtheta)``, weight
    ``1 / sigma_theta``, the first pose held), normalised; then positions as complex numbers
    (``t_j - t_i = z_i (dx + i dy)``, weight ``1 / sigma_xy``, the first pose held): two
    sparse linear least-squares solves.
    """
    import gtsam
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla

    index = {k: n for n, k in enumerate(pose_keys)}
    edges = []
    for n in range(graph.size()):
        f = graph.at(n)
        if isinstance(f, gtsam.BetweenFactorPose2):
            a, b = f.keys()
            m, cov = f.measured(), f.noiseModel().covariance()
            sxy = math.sqrt(0.5 * (cov[0, 0] + cov[1, 1]))
            edges.append((index[a], index[b], m.x(), m.y(), m.theta(), math.sqrt(cov[2, 2]), sxy))
    e = np.array(edges)
    i, j, M, N = e[:, 0].astype(int), e[:, 1].astype(int), len(e), len(pose_keys)

    def solve(coef_i, w, rhs, fixed):  # min sum |w (u_j - coef_i u_i) - w rhs|^2, u_0 fixed
        r = np.arange(M)
        A = sp.csr_matrix(
            (np.r_[w, -w * coef_i], (np.r_[r, r], np.r_[j, i])), shape=(M, N), dtype=complex
        )
        b = w * rhs - A[:, 0].toarray().ravel() * fixed
        Af = A[:, 1:]
        u = sla.spsolve((Af.conj().T @ Af).tocsc(), Af.conj().T @ b)
        return np.r_[fixed, u]

    first = values.atPose2(pose_keys[0])
    z = solve(np.exp(1j * e[:, 4]), 1.0 / e[:, 5], np.zeros(M), np.exp(1j * first.theta()))
    z /= np.abs(z)
    step = z[i] * (e[:, 2] + 1j * e[:, 3])
    t = solve(np.ones(M), 1.0 / e[:, 6], step, first.x() + 1j * first.y())
    out = gtsam.Values(values)
    for n, k in enumerate(pose_keys):
        out.update(k, gtsam.Pose2(t[n].real, t[n].imag, float(np.angle(z[n]))))
    return out


def converged_optimum(graph, values, max_iterations: int = 1000):
    """GTSAM's LM run to a standstill, then GTSAM Gauss-Newton (QR) while it lowers the error.

    ``LevenbergMarquardtOptimizer`` with ``relativeErrorTol = absoluteErrorTol = 0`` is
    iterated until three iterations in a row lower the error by less than 1e-12 of it (a
    minimum: no damping finds a lower point) or ``max_iterations``; Gauss-Newton with
    ``MULTIFRONTAL_QR`` (accurate on ill-conditioned systems) then takes steps while they
    lower the error, at most 10. Returns ``(values, lm_iterations, gn_steps)``.
    """
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(0.0)
    params.setAbsoluteErrorTol(0.0)
    lm = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    err, still = lm.error(), 0
    while still < 3 and lm.iterations() < max_iterations:
        lm.iterate()
        still = still + 1 if err - lm.error() < 1e-12 * err else 0
        err = min(err, lm.error())
    best, steps = lm.values(), 0
    gn_params = gtsam.GaussNewtonParams()
    gn_params.setLinearSolverType("MULTIFRONTAL_QR")
    gn = gtsam.GaussNewtonOptimizer(graph, best, gn_params)
    for _ in range(10):
        gn.iterate()
        if not gn.error() < err:
            break
        best, err, steps = gn.values(), gn.error(), steps + 1
    return best, int(lm.iterations()), steps


def isam2_incremental(graph, pose_keys, extra_updates: int = 3):
    """GTSAM iSAM2, one update per pose in key order (see the module docstring).

    The new pose is initialised from the current estimate of the pose before it; a new
    landmark from the current estimate of the pose that first sees it.

    Factors are grouped by the latest pose they involve; a landmark enters with its first
    sighting. Default ``ISAM2Params`` (relinearise at 0.1 every 10 updates), then
    ``extra_updates`` updates without new factors.
    """
    import gtsam

    order = {k: n for n, k in enumerate(pose_keys)}
    by_pose: dict[int, list] = {}
    for i in range(graph.size()):
        f = graph.at(i)
        if f is None:
            continue
        n = max(order[k] for k in f.keys() if k in order)
        by_pose.setdefault(n, []).append(f)
    isam = gtsam.ISAM2(gtsam.ISAM2Params())
    est = gtsam.Values()  # current estimates of the variables used to initialise new ones
    for n, key in enumerate(pose_keys):
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for f in by_pose.get(n, ()):
            g.add(f)
        for f in by_pose.get(n, ()):
            keys = list(f.keys())
            if isinstance(f, gtsam.PriorFactorPose2) and not est.exists(key) and not v.exists(key):
                v.insert(key, f.prior())
            elif isinstance(f, gtsam.BetweenFactorPose2) and keys[1] == key and not v.exists(key):
                v.insert(key, est.atPose2(keys[0]).compose(f.measured()))
            elif isinstance(f, gtsam.BetweenFactorPose2) and keys[0] == key and not v.exists(key):
                v.insert(key, est.atPose2(keys[1]).compose(f.measured().inverse()))
        for f in by_pose.get(n, ()):
            if isinstance(f, gtsam.BearingRangeFactor2D):
                x, lk = f.keys()
                if not est.exists(lk) and not v.exists(lk):
                    pose = v.atPose2(x) if v.exists(x) else est.atPose2(x)
                    br = f.measured()
                    b = br.bearing().theta()
                    local = gtsam.Point2(br.range() * math.cos(b), br.range() * math.sin(b))
                    v.insert(lk, pose.transformFrom(local))
        isam.update(g, v)
        for k in v.keys():  # only the new variables are needed again (the next pose's start)
            if est.exists(k):
                continue
            if gtsam.Symbol(k).chr() == ord("l"):
                est.insert(k, isam.calculateEstimatePoint2(k))
            else:
                est.insert(k, isam.calculateEstimatePose2(k))
        if n > 0 and est.exists(pose_keys[n - 1]):
            est.update(pose_keys[n - 1], isam.calculateEstimatePose2(pose_keys[n - 1]))
        if est.exists(key):
            est.update(key, isam.calculateEstimatePose2(key))
    for _ in range(extra_updates):
        isam.update()
    return isam.calculateEstimate()


def poses_of(values, pose_keys) -> np.ndarray:
    """``(N, 3)`` poses of ``pose_keys`` in ``values``."""
    out = np.empty((len(pose_keys), 3))
    for n, k in enumerate(pose_keys):
        p = values.atPose2(k)
        out[n] = (p.x(), p.y(), p.theta())
    return out


def odofuse_values(result, pose_keys, landmark_key=None):
    """odofuse's solution as GTSAM values under the reader's keys.

    Pose-graph logs stamp pose ``k`` at ``t = k`` (docs/formats.md section 3), so the
    trajectory time is the pose id; landmark ``id`` maps to ``landmark_key(id)``
    (``gtsam.symbol('l', id)`` for load2D).
    """
    import gtsam

    v = gtsam.Values()
    tr = result.trajectory
    at = {int(round(t)): n for n, t in enumerate(tr.t)}
    for k in pose_keys:
        p = tr.poses[at[gtsam.Symbol(k).index()]]
        v.insert(k, gtsam.Pose2(*p))
    for lid, xy in (result.extra.get("landmarks") or {}).items():
        key = landmark_key(int(lid)) if landmark_key else gtsam.symbol("l", int(lid))
        v.insert(key, gtsam.Point2(*xy))
    return v


def position_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of the position difference of two ``(N, 3)`` pose arrays (m)."""
    return float(np.sqrt(np.mean(np.sum((a[:, :2] - b[:, :2]) ** 2, axis=1))))


def dataset_config(log, path, estimator: str = "smoother", **options):
    """The odofuse run of a dataset of the wheel: every stream it has, with the file's noise.

    ``loop_closures`` when the log has them; ``landmarks`` (range-bearing) as SLAM; ``ranges``
    against the log's map when it has one (pyfg beacons), else as SLAM. ``options`` go into
    ``options.<estimator>``.
    """
    from odofuse.config import RunConfig

    sensors: dict = {}
    if log.has("loop_closures"):
        sensors["loop_closures"] = {}
    if log.has("landmarks"):
        sensors["landmarks"] = {}
        options.setdefault("slam", True)
    if log.has("ranges"):
        sensors["ranges"] = {}
        if not log.landmarks:
            options.setdefault("slam", True)
    return RunConfig(
        log=str(path),
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": [1e-3, 1e-4], "var_floor": [1e-6, 1e-8]},
        estimator=estimator,
        sensors=sensors,
        options={estimator: options},
        source=f"<{os.path.basename(str(path))}>",
    )


def apply_se2(T, xy) -> np.ndarray:
    """Points ``xy`` ``(N, 2)`` moved by the rigid transform ``T = (tx, ty, angle)``."""
    c, s = math.cos(T[2]), math.sin(T[2])
    return np.asarray(xy, dtype=float) @ np.array([[c, s], [-s, c]]) + np.asarray(T[:2])


def aligned_start(slam, log):
    """The transform of a SLAM map onto the log's known beacons, and the start pose it implies.

    No ground truth: the beacons are the map the localisation run uses. Returns
    ``(T, start)``: ``T = (tx, ty, angle)`` from :func:`odofuse.evaluation.align_se2` of the
    estimated beacons onto the known ones, and ``start = T`` composed with the first pose.
    """
    from odofuse.evaluation import align_se2

    ids = sorted(log.landmarks)
    A = np.array([slam.extra["landmarks"][i] for i in ids])
    B = np.array([log.landmarks[i] for i in ids])
    _, t, angle = align_se2(A, B)
    T = np.array([t[0], t[1], angle])
    x0 = slam.trajectory.poses[0]
    start = np.r_[apply_se2(T, x0[None, :2])[0], math.remainder(x0[2] + angle, 2 * math.pi)]
    return T, start


def range_residuals(result, log) -> np.ndarray:
    """``||p - b|| - r`` (m) of every range row at the estimated pose of its time, with the
    estimated beacons (SLAM) or the log's map."""
    beacons = result.extra.get("landmarks") or log.landmarks
    r = log.streams["ranges"]
    tr = result.trajectory
    k = np.clip(np.searchsorted(tr.t, r.t), 0, len(tr.t) - 1)
    b = np.array([beacons[int(i)] for i in r["id"]])
    return np.linalg.norm(tr.poses[k, :2] - b, axis=1) - r["range"]
