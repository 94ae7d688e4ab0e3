"""Assembly of a :class:`GraphProblem` from a log and a run config (no GTSAM objects).

Owns which sensor rows get a factor (inside the odometry span, finite, a known landmark, a
positive gyro interval) and which are counted as rejected, the keyframe of each row, the
calibration states with their priors (and the segments of a walking gyro bias,
:meth:`GraphProblem.bias_key`), the robust loss per stream, the pre-integrated
odometry and the dead-reckoned initial guess. The factors themselves are made by
:mod:`odofuse.estimators.graph.factors`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from odofuse import se2
from odofuse.declarations import GraphOptions
from odofuse.errors import ConfigError
from odofuse.estimators.common import initial_state, odometry_inputs, odometry_stream_name
from odofuse.estimators.graph.calibration import OdometryCalibration, odometry_calibration_for
from odofuse.estimators.graph.keyframes import (
    attach_headings,
    gyro_rotation_track,
    keyframe_times,
    preintegrate,
    preintegrate_gyro,
    wheel_rotation_track,
)
from odofuse.estimators.graph.keys import C, W, model_kind
from odofuse.estimators.graph.loops import (
    STREAM,
    file_odometry,
    is_pose_graph,
    loop_block,
    loop_closures,
    loop_times,
)
from odofuse.estimators.graph.slam import log_with_ids, slam_initial_landmarks

LANDMARK_SENSORS = ("BeaconRange", "LandmarkBearing", "LandmarkRangeBearing")


@dataclass
class Measurement:
    """A sensor row that gets a factor: its stream, row, keyframe(s) and landmark id."""

    stream: str
    index: int  # row in the stream (the first of an averaged heading)
    keyframe: int  # keyframe index
    row: dict
    landmark: int | None = None
    rows: int = 1  # stream rows the factor stands for (attach_headings averages several)
    added_at: int | None = None  # keyframe whose update adds the factor (default: keyframe)


@dataclass(frozen=True)
class GyroIncrements:
    """A gyro stream pre-integrated between keyframes (:func:`preintegrate_gyro`).

    ``interval[n]`` is the keyframe interval ``(kt[i], kt[i+1])`` of the ``n``-th heading
    increment ``dtheta`` (rad) with variance ``var`` (rad^2) over ``T`` s of gyro data, summing
    ``samples`` gyro rows.
    """

    interval: np.ndarray
    dtheta: np.ndarray
    var: np.ndarray
    T: np.ndarray
    samples: np.ndarray


@dataclass
class GraphProblem:
    """Everything the three solvers share (built once per run by :func:`build_problem`).

    Attributes
    ----------
    kt : ndarray (K,)
        Keyframe times (s).
    deltas, covs : ndarray (K-1, 3), (K-1, 3, 3)
        Pre-integrated odometry (body frame, GTSAM tangent covariance).
    pose0, P0 : ndarray (3,), (3, 3)
        Initial pose and its world-frame covariance.
    models : dict
        Stream -> measurement model.
    measurements : list
        Sensor rows with their keyframe, in time order.
    calib : dict
        Calibration state name -> (key, initial value, sigma).
    landmarks : dict
        Landmark id -> (2,) position: the map, or the SLAM initial guess.
    rejected : dict
        Stream -> rows that got no factor (outside the odometry span, unknown landmark, ...).
    gyro : dict
        Gyro stream -> :class:`GyroIncrements` (one heading-increment factor per keyframe
        interval; gyro times are not keyframes). Several gyro streams each get their own
        factors and, when calibrated, their own bias (``gyro_bias``, ``gyro_bias:gyro_2``).
    bias_walk : dict
        ``calib`` name -> random walk (rad/s/sqrt(s)) of a gyro bias whose ``bias_walk`` is
        positive. Such a bias is piecewise constant: one variable per keyframe interval
        (:meth:`bias_key`), consecutive ones tied by :meth:`bias_step_sigma`. Without an entry
        the bias is one constant variable.
    """

    kt: np.ndarray
    deltas: np.ndarray
    covs: np.ndarray
    pose0: np.ndarray
    P0: np.ndarray
    models: dict
    measurements: list
    calib: dict
    landmarks: dict
    options: GraphOptions
    odometry_stream: str
    odometry_rows: int
    rejected: dict
    robust: dict
    odometry_calibration: OdometryCalibration | None = None
    G: np.ndarray | None = None
    loops: list = field(default_factory=list)  # graph.loops.Loop records
    pose_graph: bool = False  # odometry edges as stored in a pose-graph file (graph.loops)
    gyro: dict = field(default_factory=dict)
    # (stream, model state) -> name in ``calib`` where a stream has its own copy of a state
    # its model shares by name: ``gyro_bias:gyro_2``, the bias of a second gyro
    calib_alias: dict = field(default_factory=dict)
    bias_walk: dict = field(default_factory=dict)

    def bias_key(self, name: str, interval: int) -> int:
        """GTSAM key of calibration state ``name`` over keyframe interval ``interval``.

        The state's one key (``calib[name][0]``) unless it walks (:attr:`bias_walk`): then
        interval 0 has that key (and its prior) and interval ``j >= 1`` its own ``W(n, j)``.
        """
        key = self.calib[name][0]
        if name not in self.bias_walk or interval <= 0:
            return key
        import gtsam

        return W(gtsam.Symbol(key).index(), interval)

    def final_key(self, name: str) -> int:
        """GTSAM key of ``name``'s value at the end of the log (its last segment if it walks)."""
        return self.bias_key(name, len(self.kt) - 2)

    def bias_step_sigma(self, name: str, j: int) -> float:
        """rad/s, sigma of ``b_j - b_{j-1}`` for a walking bias (``j >= 1``).

        ``bias_walk * sqrt(tau)`` with ``tau`` the time between the centres of keyframe
        intervals ``j-1`` and ``j`` (each variable is the bias over its interval).
        """
        tau = 0.5 * float(self.kt[j + 1] - self.kt[j - 1])
        return float(self.bias_walk[name]) * math.sqrt(tau)

    def prior_sigma_at(self, name: str, t):
        """The prior sigma of ``name``'s value at times ``t`` (s): its prior sigma, grown by
        the walk since the first keyframe (``sqrt(sigma^2 + walk^2 (t - t_0))``)."""
        sigma = float(self.calib[name][2])
        if name not in self.bias_walk:
            return sigma
        walk = float(self.bias_walk[name])
        return np.sqrt(sigma**2 + walk**2 * (np.asarray(t, dtype=float) - float(self.kt[0])))

    def state_name(self, stream: str, state: str) -> str:
        """The ``calib`` name of ``stream``'s calibration state ``state``."""
        return self.calib_alias.get((stream, state), state)

    @property
    def odometry_key(self) -> int:
        """Key of the odometry calibration vector (``o0``)."""
        import gtsam

        return gtsam.symbol("o", 0)

    def dead_reckoning(self) -> np.ndarray:
        """Keyframe poses ``(K, 3)`` obtained by composing the odometry factors from ``pose0``."""
        # pose_{i+1} = pose_i (+) d_i: theta by a running sum, positions by summing the
        # increments rotated into the world (head-to-tail composition, 002 source)
        theta = self.pose0[2] + np.concatenate([[0.0], np.cumsum(self.deltas[:, 2])])
        c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
        dx, dy = self.deltas[:, 0], self.deltas[:, 1]
        step = np.column_stack([c * dx - s * dy, s * dx + c * dy])
        xy = self.pose0[:2] + np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])
        return np.column_stack([xy, se2.wrap(theta)])


def _rotation_tracks(gyro_rows, models, t_odo, U, model) -> list:
    """Rotation tracks for :func:`attach_headings`: the first gyro stream (its bias prior
    value subtracted, its prior sigma as the bias uncertainty), then the wheels."""
    tracks = []
    if gyro_rows:
        name, rows = next(iter(gyro_rows.items()))
        prior = getattr(models[name], "calib_prior", dict)()
        bias, bias_sigma = prior.get("gyro_bias", (0.0, 0.0))
        t_prev, t, wz, var = np.array(rows).T
        tracks.append((*gyro_rotation_track(t_prev, t, wz, var, bias), float(bias_sigma)))
    tracks.append((*wheel_rotation_track(t_odo, U, model), 0.0))
    return tracks


def _samples(stream, order, model, t_lo, t_hi):
    """A stream's rows in time order that the graph takes, vectorised (the per-row loop of
    :func:`build_problem` costs seconds at 50 Hz): inside the odometry span, every value
    finite. Returns the count rejected, their times, row indices and variances as ``model.R``
    gives them (a ``sigma`` column or the model's sigma)."""
    t = stream.t[order]
    ok = (t >= t_lo) & (t <= t_hi) & np.all(np.isfinite(stream.values[order]), axis=1)
    idx = order[ok]
    if "sigma" in stream.columns:
        var = stream["sigma"][idx] ** 2
    else:
        var = np.full(idx.size, float(model.R(None)[0, 0]))
    return int(np.count_nonzero(~ok)), t[ok], idx, var


def _gyro_rows(stream, order, model, t_lo, t_hi) -> tuple[int, np.ndarray]:
    """A gyro stream's samples to pre-integrate (:func:`_samples`): the count rejected (also
    the first sample and any sample at the time of the one before) and the rows ``(t_prev, t,
    wz, variance)`` ``(K, 4)``, ``wz`` as ``model.z`` gives it. Each sample covers the time
    since the previous kept one."""
    _, tk, idx, var = _samples(stream, order, model, t_lo, t_hi)
    if idx.size < 2:
        return len(order), np.empty((0, 4))
    rows = np.column_stack([tk[:-1], tk[1:], stream["wz"][idx[1:]], var[1:]])
    rows = rows[tk[1:] > tk[:-1]]  # a sample at the time of the one before covers nothing
    return len(order) - len(rows), rows


def _compass_rows(stream, order, model, t_lo, t_hi):
    """Rows of a compass stream to attach to keyframes (:func:`_samples`): the count rejected
    and ``(t, row index, heading, variance)`` arrays in time order, the heading as
    ``model.z`` gives it."""
    rejected, tk, idx, var = _samples(stream, order, model, t_lo, t_hi)
    return rejected, (tk, idx, se2.wrap(stream["heading"][idx]), var)


def build_problem(log, config, estimator: str) -> GraphProblem:
    """Keyframes, pre-integrated odometry and the sensor rows of a run (no GTSAM objects).

    Raises
    ------
    ConfigError, InputError
        Bad options (naming the key and file) or an unusable log.
    """
    from odofuse.measurements import measurement_models
    from odofuse.motion import motion_model_from_config

    options = config.estimator_options(estimator)
    if options.slam and estimator == "fixed_lag":
        raise ConfigError(
            "slam (unknown landmarks) is implemented for the smoother and isam2 only",
            file=config.source,
            key=f"options.{estimator}.slam",
        )
    model = motion_model_from_config(config)
    t_odo, U = odometry_inputs(log, model)
    pose0, P0 = initial_state(config, log)
    models = measurement_models(config, log_with_ids(log) if options.slam else log)
    loops_cfg = loop_block(config)
    pose_graph = is_pose_graph(log, odometry_stream_name(model))
    if pose_graph:  # one keyframe per pose, each edge with the file's covariance
        t_odo, pg_deltas, pg_covs = file_odometry(log, odometry_stream_name(model), t_odo, model)
    t_lo, t_hi = float(t_odo[0]), float(t_odo[-1])

    rejected: dict[str, int] = {}
    pending: list[tuple[float, Measurement]] = []
    # compass readings follow the keyframe policy when it has a trigger of its own: they are
    # moved to their nearest keyframe and averaged (attach_headings), not keyframes
    attach = not pose_graph and (
        options.keyframe_dt > 0 or options.keyframe_ds > 0 or options.keyframe_dtheta > 0
    )
    heading_rows: dict[str, tuple] = {}  # stream -> (t, row index, heading, variance)
    gyro_rows: dict[str, list] = {}  # stream -> (t_prev, t, wz, var) of accepted samples
    for name, m in models.items():
        if not log.has(name):
            continue
        stream = log.streams[name]
        order = np.argsort(stream.t, kind="stable")  # a few logs (Plaza) are not sorted
        kind = model_kind(m)
        if kind == "CompassHeading" and attach:
            rejected[name], heading_rows[name] = _compass_rows(stream, order, m, t_lo, t_hi)
            continue
        if kind == "GyroYawRate":
            rejected[name], rows = _gyro_rows(stream, order, m, t_lo, t_hi)
            if len(rows):
                gyro_rows[name] = rows
            continue
        n_rej = 0
        for i in order:
            t = float(stream.t[i])
            if not (t_lo <= t <= t_hi):
                n_rej += 1
                continue
            row = stream.row(int(i))
            if not all(math.isfinite(v) for v in row.values()):
                n_rej += 1
                continue
            meas = Measurement(name, int(i), -1, row)
            if kind in LANDMARK_SENSORS:
                lid = int(row["id"])
                if not options.slam and lid not in log.landmarks:
                    n_rej += 1
                    continue
                meas.landmark = lid
            pending.append((t, meas))
        rejected[name] = n_rej

    # gyro samples are pre-integrated between keyframes: only the ends of each gyro stream
    # are keyframes, so that every interval in between is covered completely
    gyro_ends = [t for rows in gyro_rows.values() for t in (rows[0][0], rows[-1][1])]
    sensor_times = np.array([t for t, _ in pending] + gyro_ends)
    if loops_cfg is not None:
        sensor_times = np.concatenate([sensor_times, loop_times(log)])
        sensor_times = sensor_times[(sensor_times >= t_lo) & (sensor_times <= t_hi)]
    kt = t_odo if pose_graph else keyframe_times(t_odo, U, model, sensor_times, options)
    for t, meas in pending:
        meas.keyframe = int(np.searchsorted(kt, t))
    gyro = {
        name: GyroIncrements(*preintegrate_gyro(*np.array(rows).T, kt))
        for name, rows in gyro_rows.items()
    }
    if heading_rows:
        tracks = _rotation_tracks(gyro_rows, models, t_odo, U, model)
        for name, rows in heading_rows.items():
            t_r, idx, z, var = rows
            for k, zk, vk, n, first, last in zip(
                *attach_headings(t_r, z, var, kt, tracks), strict=True
            ):
                row = {"heading": float(zk), "sigma": math.sqrt(vk)}
                # causal for iSAM2's online estimate: added with the keyframe after the last
                # reading (unless the fixed-lag window would have dropped keyframe k by then)
                late = t_r[last] > kt[k] and k + 1 < kt.size
                dropped = late and estimator == "fixed_lag" and kt[k + 1] - kt[k] >= options.lag
                added_at = int(k) + 1 if late and not dropped else None
                meas = Measurement(
                    name, int(idx[first]), int(k), row, rows=int(n), added_at=added_at
                )
                pending.append((float(kt[k]), meas))
    pending.sort(key=lambda tm: (tm[1].keyframe, tm[1].stream))
    odo_cal = odometry_calibration_for(
        model,
        options.odometry_calibration,
        f"options.{estimator}.odometry_calibration",
        config.source,
    )
    G = None
    # a pose-graph file is a whole (Gaussian) problem of relative poses: odometry_calibration
    # auto and the default gate loss do not apply to it (GTSAM's optimum of the file is its
    # answer); an explicit odometry_calibration is an error
    if pose_graph and "odometry_calibration" not in getattr(options, "_explicit", ()):
        odo_cal = None
    if pose_graph and odo_cal is not None:
        raise ConfigError(
            "a pose-graph log has relative poses, not drive inputs, to calibrate",
            file=config.source,
            key=f"options.{estimator}.odometry_calibration",
        )
    if pose_graph:
        deltas, covs = pg_deltas, pg_covs
    elif odo_cal is None:
        deltas, covs = preintegrate(t_odo, U, model, kt)
    else:
        deltas, covs, G = preintegrate(t_odo, U, model, kt, odo_cal)

    calib: dict[str, tuple[int, float, float]] = {}
    alias: dict[tuple[str, str], str] = {}
    walks: dict[str, float] = {}
    for stream, m in models.items():
        clones = set(getattr(m, "clones", lambda: {})())
        prior = getattr(m, "calib_prior", lambda: {})()
        for state in getattr(m, "calib_states", ()):
            if state in clones:
                continue
            if state == "gyro_bias" and state in calib:  # a second IMU has its own bias
                alias[stream, state] = f"{state}:{stream}"
            name = alias.get((stream, state), state)
            if name in calib:
                continue
            value, sigma = prior.get(state, (0.0, 1.0))
            calib[name] = (C(len(calib)), float(value), float(sigma))
            walk = float(getattr(m, "calib_walk", dict)().get(state, 0.0))
            if state == "gyro_bias" and stream in gyro and walk > 0 and kt.size > 2:
                walks[name] = walk

    dropped = getattr(options, "gate_defaults", frozenset()) if pose_graph else frozenset()
    robust = {
        s: ("none", 0.0) if s in dropped else options.robust.get(s, ("none", 0.0)) for s in models
    }
    robust[odometry_stream_name(model)] = options.robust.get(
        odometry_stream_name(model), ("none", 0.0)
    )
    robust[STREAM] = options.robust.get(STREAM, ("none", 0.0))
    problem = GraphProblem(
        kt,
        deltas,
        covs,
        pose0,
        P0,
        models,
        [m for _, m in pending],
        calib,
        {int(i): np.asarray(p, dtype=float) for i, p in log.landmarks.items()},
        options,
        odometry_stream_name(model),
        len(U),
        rejected,
        robust,
        odo_cal,
        G,
        gyro=gyro,
        pose_graph=pose_graph,
        calib_alias=alias,
        bias_walk=walks,
    )
    if loops_cfg is not None:
        lag = options.lag if estimator == "fixed_lag" else None
        problem.loops, rejected[STREAM] = loop_closures(log, loops_cfg, kt, lag)
    if options.slam:
        problem.landmarks = slam_initial_landmarks(
            problem.measurements, problem.models, problem.dead_reckoning(), options.slam_grid
        )
    return problem


def convex_problem(problem: GraphProblem) -> GraphProblem | None:
    """``problem`` with Huber's loss in place of every sensor stream's Tukey loss, at the same
    thresholds, or None when no sensor stream has Tukey's.

    Tukey's loss gives a reading beyond its threshold no pull at all, which is what rejects a
    gross reading (the filters' gate, ``declarations.graph.gate_loss``); but from a start that
    has drifted past the threshold (dead reckoning, or an incremental solver's prediction
    after an outage) it ignores the very readings that correct the drift, for good. Huber's
    loss is convex: its influence is bounded but never vanishes, so a reading far from the
    start still pulls the estimate towards it. The graph solvers therefore solve the Huber
    problem first and the Tukey problem from there (graduated non-convexity in two steps):
    the batch smoother (:func:`~odofuse.estimators.graph.solvers._convex_start`), iSAM2
    (online with Huber; its final pass is
    the Tukey solve) and the fixed-lag smoother (it has no final pass: the rows that pass the
    filters' gate get Huber's loss; :func:`odofuse.estimators.graph.isam2.run_fixed_lag`).
    """
    tukey = {
        s: k for s, (kind, k) in problem.robust.items() if kind == "tukey" and s in problem.models
    }
    if not tukey:
        return None
    return dataclasses.replace(
        problem, robust={**problem.robust, **{s: ("huber", k) for s, k in tukey.items()}}
    )
