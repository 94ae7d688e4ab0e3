"""Incremental SLAM: iSAM2 with unknown landmarks entering the graph as they are first fixed.

Owns :func:`incremental_slam` (used by ``estimator: isam2`` with ``slam: true``, and by the
smoother's ``slam_init: incremental`` as its initial values). A new landmark enters the graph
with the measurement that first fixes it, initialised from the *current* iSAM2 estimate of the
poses rather than from dead reckoning:

* a range-bearing sighting places it at once
  (:func:`~odofuse.estimators.graph.landmarks.from_sighting`);
* ranges are held back until :func:`~odofuse.estimators.graph.landmarks.multilaterate` fixes
  the landmark from at least :data:`MIN_RANGES` of them (a single range leaves a landmark
  undetermined, which iSAM2 cannot factor); then the landmark and all its held ranges enter
  together. Ranges still held at the end of the log are counted as rejected.

Pose keyframes older than the last :data:`~odofuse.estimators.graph.isam2_window.KEEP` leave
iSAM2's tree in batches (:class:`~odofuse.estimators.graph.isam2_window.KeyframeWindow`, as on
the localisation path: bounded update cost); landmarks stay, and so does every keyframe from
the oldest one a later factor refers to: a landmark seen again after ``KEEP`` keyframes out of
sight counts as a loop closure to its previous sighting (:func:`resighting_loops`). A loop
closure reaching further back than ``KEEP`` keyframes keeps every keyframe in iSAM2 (as on the
localisation path: :meth:`~odofuse.estimators.graph.isam2_window.KeyframeWindow.loops_reach_back`),
and so does a range-only landmark: there the marginal factors fix the linearisation of landmarks
multilaterated from early, poor poses, and on Plaza1's first 400 s the final LM then stopped at
its cap at graph error 20,610 instead of 595.8 (unwindowed); so a problem with any range-only
landmark keeps every keyframe in iSAM2 (as before issue 17).
The window's :attr:`graph` and :meth:`estimate` hold the whole run for the final batch pass.

Bearing-only landmarks are not initialised incrementally (their rows are counted as
rejected). The calibration freeze of :func:`~odofuse.estimators.graph.isam2.run_isam2` is not
available here.
"""

from __future__ import annotations

import time

import numpy as np

from odofuse.errors import ConfigError
from odofuse.estimators.graph import isam2_window
from odofuse.estimators.graph.factors import Factors
from odofuse.estimators.graph.innovations import current_values, observe
from odofuse.estimators.graph.isam2_window import KeyframeWindow
from odofuse.estimators.graph.keys import X, model_kind
from odofuse.estimators.graph.landmarks import from_sighting, multilaterate
from odofuse.estimators.graph.loops import oldest_referenced
from odofuse.estimators.graph.problem import GraphProblem, convex_problem

#: Ranges a landmark needs before it is multilaterated into the graph.
MIN_RANGES = 5
# The clock of the latency figures (wall time); benchmarks/bench_graph.py sets it to
# ``time.thread_time`` as it does ``isam2._clock``.
_clock = time.perf_counter

#: Keyframes between two reads of the current pose estimate, which the next keyframes are
#: dead-reckoned from (a read makes iSAM2 back-substitute; new landmarks always read it).
ESTIMATE_EVERY = 10


def cholesky_suits(problem: GraphProblem) -> bool:
    """Whether iSAM2 first tries GTSAM's default Cholesky factorisation on ``problem``.

    odofuse's iSAM2 runs factorise by QR because pinned landmarks (sigma
    ``known_landmark_sigma``, 1e-6 m), the floored covariances of drive odometry and
    calibration variables make the normal equations too ill-conditioned for Cholesky. A pose
    graph whose variables are its poses and unknown (SLAM) landmarks has none of them (its
    edges carry the file's covariances, unfloored), and there Cholesky is several times faster
    (``w10000.graph``: the iSAM2 pass 52 s against 219 s with QR; Victoria Park's SLAM pass
    22 s). Cholesky can still meet an indeterminate system on a badly conditioned graph
    (``w20000.txt`` at keyframe 1195, as plain GTSAM's default iSAM2 does): the caller then
    runs the pass again with QR.
    """
    return (
        problem.pose_graph
        and not problem.calib
        and problem.odometry_calibration is None
        and (problem.options.slam or all(m.landmark is None for m in problem.measurements))
    )


def resighting_loops(landmark_rows: dict[int, list], keep: int) -> list[tuple[int, int]]:
    """``(later, earliest)`` keyframe pairs of landmark sightings that close a loop.

    A landmark seen again at keyframe ``j`` after ``keep`` or more keyframes out of sight
    (the robot left and came back) ties ``j`` to the landmark's previous sighting ``p`` as a
    loop closure between the two poses does: had ``p`` left iSAM2's tree, it and the poses
    after it would stay at the linearisation they had, and the landmark's new evidence could
    not move them. On Victoria Park (trees seen again lap after lap) the window without this
    rule stopped the final LM in a local minimum at graph error 3,026.2 instead of 2,339.22;
    with it, 6,868 of the 6,969 keyframes still leave the tree over the run and the final LM
    reaches 2,339.2195. A landmark in view all along closes no loop.

    Parameters
    ----------
    landmark_rows : dict
        Keyframe -> the landmark measurements added with it.
    keep : int
        Keyframes the window keeps (``isam2_window.KEEP``).
    """
    last: dict[int, int] = {}
    out = []
    for j in sorted(landmark_rows):
        for m in landmark_rows[j]:
            prev = last.get(m.landmark, j)
            if j - prev >= keep:
                out.append((j, prev))
            last[m.landmark] = j
    return out


def incremental_slam(problem: GraphProblem, params, source: str = "<config>", monitor=None):
    """Run iSAM2 over the keyframes of a SLAM problem (module docstring).

    Parameters
    ----------
    problem : GraphProblem
        With ``options.slam`` set.
    params : gtsam.ISAM2Params
    source : str
        Config file, for errors.
    monitor : FilterMonitor, optional
        Fed the NIS of each keyframe's sensor rows against iSAM2's prediction before its
        update (:func:`odofuse.estimators.graph.innovations.observe`, as on the localisation
        path): the rows of absolute sensors and the sightings of landmarks already in the
        graph (a landmark's first fix has nothing that predicts it).

    Returns
    -------
    isam : gtsam.ISAM2
        After ``options.final_relinearizations`` forced relinearising updates (without the
        marginalised keyframes).
    fac : Factors
        The factors added (``fac.created``, ``fac.used``; held-back ranges are in
        ``problem.rejected``). A stream with Tukey's loss was given to iSAM2 with Huber's at
        the same threshold; ``fac.final`` then holds every factor with the configured loss
        (the graph of the final pass), else it is None.
    window : KeyframeWindow
        Every factor of the run and the estimates of the keys marginalised online.
    latency : tuple of two lists of float
        s, the time of each ``ISAM2.update`` and of each whole per-keyframe step (factors,
        landmark initialisation, update, pose reads), by :data:`_clock`.
    """
    import gtsam

    if problem.options.calibration_freeze:
        raise ConfigError(
            "calibration_freeze is not available with slam", source, "options.isam2.slam"
        )

    # a stream with Tukey's loss is updated with Huber's (convex_problem): a landmark whose
    # sightings all lie beyond Tukey's threshold would have no information left (example.graph
    # stopped at an indeterminate l110); fac.final holds the factors with the configured losses
    soft = convex_problem(problem)
    fac = Factors(soft or problem, final_robust=None if soft is None else problem.robust)
    graph, values = fac.static()
    for key in fac.landmark_keys.values():  # landmarks enter with their first fix
        values.erase(key)
    held: dict[int, list] = {}
    landmark_rows: dict[int, list] = {}
    for i, ms in fac.by_kf.items():
        landmark_rows[i] = [m for m in ms if m.landmark is not None]
        fac.by_kf[i] = [m for m in ms if m.landmark is None]
    frozen = gtsam.KeyList()
    for key, _, _ in problem.calib.values():
        frozen.push_back(key)
    if problem.odometry_calibration is not None:
        frozen.push_back(problem.odometry_key)
    placed: dict[int, int] = {}  # landmark id -> the keyframe that placed it in the graph
    # range-only landmarks: no window (module docstring)
    range_only = any(
        model_kind(problem.models[m.stream]) == "BeaconRange"
        for ms in landmark_rows.values()
        for m in ms
    )
    # a landmark seen again after its previous sighting's keyframe could have left keeps
    # that keyframe in the tree; a loop closure reaching back that far keeps every keyframe
    # (KeyframeWindow.loops_reach_back), as does a range-only landmark
    hold = oldest_referenced(resighting_loops(landmark_rows, isam2_window.KEEP))
    unwindowed = range_only or KeyframeWindow.loops_reach_back(problem.loops)
    window = KeyframeWindow()
    latency, step = [], []

    def add(meas):
        f = fac.measurement(meas)
        graph.add(f)
        if fac.final is not None:  # the factor with the configured loss, for the final pass
            loss = fac.final_robust.get(meas.stream)
            twin = loss is not None and loss != fac.p.robust.get(meas.stream)
            fac.final.add(fac.with_loss(meas, f, loss) if twin else f)
        fac.created.append((meas, f))
        fac.used[meas.stream] = fac.used.get(meas.stream, 0) + 1
        return f

    def pose_now(k: int, i: int, current) -> np.ndarray:
        if k == i and i > 0:  # the current estimate of the previous pose, plus the odometry
            current = window.pose(isam, X(i - 1)).compose(gtsam.Pose2(*problem.deltas[i - 1]))
        p = current if k == i else window.pose(isam, X(k))
        return np.array([p.x(), p.y(), p.theta()])

    isam = gtsam.ISAM2(params)
    current = gtsam.Pose2(*problem.pose0)
    for i in range(len(problem.kt)):
        t_step = _clock()
        if i > 0:
            current = current.compose(gtsam.Pose2(*problem.deltas[i - 1]))
        fac.keyframe(i, current, graph, values)
        for meas in landmark_rows.get(i, ()):
            lid, kind = meas.landmark, model_kind(problem.models[meas.stream])
            key = fac.landmark_keys[lid]
            if lid in placed:
                pos = graph.size()
                f = add(meas)
                if placed[lid] < i:  # in iSAM2 before this keyframe: the sighting is tested
                    fac.rows.append((pos, meas, f))
            elif kind == "LandmarkRangeBearing":
                lm = from_sighting(pose_now(i, i, current), meas.row["range"], meas.row["bearing"])
                values.insert(key, gtsam.Point2(*lm))
                placed[lid] = i
                add(meas)
            elif kind == "BeaconRange":
                held.setdefault(lid, []).append(meas)
                rows = held[lid]
                if len(rows) < MIN_RANGES:
                    continue
                m = problem.models[meas.stream]
                P = np.array([pose_now(r.keyframe, i, current)[:2] for r in rows])
                R = np.array([float(r.row["range"]) for r in rows])
                sig = np.array([float(np.sqrt(m.R(r.row)[0, 0])) for r in rows])
                lm = multilaterate(P, R, sig)
                if lm is None:
                    continue
                values.insert(key, gtsam.Point2(*lm))
                placed[lid] = i
                for r in held.pop(lid):
                    add(r)
            else:
                held.setdefault(lid, []).append(meas)
        if monitor is not None and i > 0 and fac.rows:
            observe(monitor, isam, fac, graph, values, current_values)
        window.add(graph, values)
        window.hold = 0 if unwindowed else hold(i)
        t0 = _clock()
        window.update(isam, i, graph, values, frozen)  # old keyframes may leave
        latency.append(_clock() - t0)
        if i > 0 and i % ESTIMATE_EVERY == 0:
            current = isam.calculateEstimatePose2(X(i))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        step.append(_clock() - t_step)
    for _ in range(problem.options.final_relinearizations):
        isam.update(force_relinearize=True)
    for lid, rows in held.items():
        for r in rows:
            problem.rejected[r.stream] = problem.rejected.get(r.stream, 0) + 1
        fac.landmark_keys.pop(lid, None)
    return isam, fac, window, (latency, step)
