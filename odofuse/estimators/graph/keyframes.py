"""Keyframes and odometry pre-integration of the graph (no GTSAM objects).

Owns where keyframes fall (:func:`keyframe_times`: the odometry span's ends, sensor times
and the dt / ds / dtheta triggers) and the relative pose, body-frame covariance and
calibration sensitivity of the odometry between consecutive keyframes (:func:`preintegrate`,
``MotionModel.relative`` vectorised over all intervals); an odometry step straddling a
keyframe is split, its wheel / increment inputs scaled by the time fraction.
"""

from __future__ import annotations

import numpy as np

from odofuse import se2
from odofuse.declarations import GraphOptions


def keyframe_times(t_odo, U, model, sensor_times, options: GraphOptions) -> np.ndarray:
    """Keyframe times: the odometry span's ends, sensor times and the dt/ds/dtheta triggers.

    Parameters
    ----------
    t_odo : ndarray (N+1,)
        Times of the poses of the odometry steps (s).
    U : ndarray (N, n)
        Drive inputs per step.
    model : MotionModel
    sensor_times : ndarray (M,)
        Times of the sensor rows that get a factor (inside ``[t_odo[0], t_odo[-1]]``).
    options : GraphOptions

    Returns
    -------
    ndarray (K,)
        Strictly increasing keyframe times (s).
    """
    t0, t1 = float(t_odo[0]), float(t_odo[-1])
    parts = [np.array([t0, t1]), np.asarray(sensor_times, dtype=float)]
    if options.keyframe_every_step:
        parts.append(t_odo)
    if options.keyframe_dt > 0:
        parts.append(np.arange(t0, t1, options.keyframe_dt))
    if (options.keyframe_ds > 0 or options.keyframe_dtheta > 0) and len(U):
        delta, _ = model.increment(U)
        for col, step in ((None, options.keyframe_ds), (2, options.keyframe_dtheta)):
            if step <= 0:
                continue
            inc = np.hypot(delta[:, 0], delta[:, 1]) if col is None else np.abs(delta[:, 2])
            cum = np.concatenate([[0.0], np.cumsum(inc)])
            bucket = np.floor(cum / step)
            parts.append(t_odo[1:][np.diff(bucket) > 0])
    return np.unique(np.concatenate(parts))


def preintegrate(t_odo, U, model, kt, odometry_calibration=None):
    """Relative poses and body-frame covariances between consecutive keyframes.

    Odometry step ``k`` spans ``(t_odo[k], t_odo[k+1]]``; a step cut by a keyframe is split
    into pieces whose wheel / increment inputs are scaled by their time fraction.

    Returns
    -------
    deltas : ndarray (K-1, 3)
        ``[dx, dy, dtheta]`` of keyframe ``i+1`` in the frame of keyframe ``i``.
    covs : ndarray (K-1, 3, 3)
        Their covariances in GTSAM's ``Pose2`` tangent convention (``MotionModel.relative``).
    G : ndarray (K-1, 3, m)
        Only with ``odometry_calibration`` (an :class:`OdometryCalibration`): the tangent
        change of each relative pose per unit change of the calibration parameters.
    """
    t_odo = np.asarray(t_odo, dtype=float)
    kt = np.asarray(kt, dtype=float)
    breaks = np.unique(np.concatenate([t_odo, kt]))
    breaks = breaks[(breaks >= kt[0]) & (breaks <= kt[-1])]
    a, b = breaks[:-1], breaks[1:]
    step = np.clip(np.searchsorted(t_odo, b, side="left") - 1, 0, len(U) - 1)
    frac = (b - a) / np.maximum(t_odo[step + 1] - t_odo[step], 1e-300)
    kinds = getattr(model.drive, "input_kinds", ("wheel",) * U.shape[1])
    scaled = np.array([kind != "steer" for kind in kinds])
    pieces = np.where(scaled, U[step] * frac[:, None], U[step])
    owner = np.searchsorted(kt, b, side="left") - 1  # keyframe interval of each piece
    if odometry_calibration is None:
        return _preintegrate_pieces(model, pieces, owner, len(kt) - 1)
    D = odometry_calibration.input_jacobian(pieces, b - a)
    return _preintegrate_pieces(model, pieces, owner, len(kt) - 1, D)


def _preintegrate_pieces(model, pieces, owner, n_intervals, D=None):
    """Vectorised ``MotionModel.relative`` of every keyframe interval at once.

    The body-frame (GTSAM tangent) covariance obeys, piece by piece,
    ``Sigma <- Ad(inc^-1) Sigma Ad(inc^-1)^T + T J Sigma_u J^T T^T`` with ``J = J_delta_u`` (the
    increment's Jacobian in the start frame) and ``T = blockdiag(R(dtheta)^T, 1)`` moving that
    noise into the tangent at the piece's end; the same first-order propagation as the
    world-frame recursion of ``dead_reckon`` followed by ``se2.cov_world_to_body`` (tested
    equal to ``MotionModel.relative``). Intervals run in parallel, padded with identity pieces.
    With ``D`` ``(P, n, m)`` (input change per unit calibration parameter) the sensitivity
    ``G <- Ad(inc^-1) G + T J D`` is accumulated by the same recursion and returned third.
    """
    deltas = np.zeros((n_intervals, 3))
    covs = np.zeros((n_intervals, 3, 3))
    G = None if D is None else np.zeros((n_intervals, 3, D.shape[2]))
    if len(pieces) == 0:
        return (deltas, covs) if D is None else (deltas, covs, G)
    inc, J = model.increment(pieces)
    var = model.errors.variances(model.drive, pieces)
    Qa = np.einsum("pik,pk,pjk->pij", J, var, J)
    c, sn = np.cos(inc[:, 2]), np.sin(inc[:, 2])
    T = np.zeros((len(pieces), 3, 3))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1], T[:, 2, 2] = c, sn, -sn, c, 1.0
    Q = T @ Qa @ np.swapaxes(T, 1, 2)
    TJD = None if D is None else T @ J @ D
    # Adjoint of inc^-1 (GTSAM Pose2::AdjointMap of the inverse): [[R^T, R^T [-y; x]], [0, 1]]
    x, y = inc[:, 0], inc[:, 1]
    A = np.zeros((len(pieces), 3, 3))
    A[:, :2, :2] = T[:, :2, :2]
    A[:, 0, 2] = c * (-y) + sn * x
    A[:, 1, 2] = -sn * (-y) + c * x
    A[:, 2, 2] = 1.0
    start = np.searchsorted(owner, np.arange(n_intervals), side="left")
    count = np.searchsorted(owner, np.arange(n_intervals), side="right") - start
    for j in range(int(count.max())):
        live = np.flatnonzero(count > j)
        idx = start[live] + j
        deltas[live] = se2.compose(deltas[live], inc[idx])
        Ai = A[idx]
        covs[live] = Ai @ covs[live] @ np.swapaxes(Ai, 1, 2) + Q[idx]
        if G is not None:
            G[live] = Ai @ G[live] + TJD[idx]
    covs = 0.5 * (covs + np.swapaxes(covs, 1, 2))
    return (deltas, covs) if G is None else (deltas, covs, G)


def preintegrate_gyro(t_prev, t, wz, var_rate, kt):
    """Gyro samples between keyframes summed into one heading increment per interval.

    Sample ``k`` measures the mean yaw rate ``wz[k]`` over ``(t_prev[k], t[k]]`` with rate
    variance ``var_rate[k]`` (rad^2/s^2), i.e. a heading change ``wz dt`` of variance
    ``var_rate dt^2`` (the per-sample model of :class:`odofuse.measurements.GyroYawRate`).
    A sample cut by a keyframe is split: a piece of duration ``tau`` gets ``wz tau`` and
    variance ``var_rate dt tau`` (white rate noise of density ``var_rate dt``), so the pieces
    of one sample add up to the sample's own variance. With a constant bias ``b`` the true
    heading change of interval ``i`` is ``dtheta[i] - b T[i]``.

    Parameters
    ----------
    t_prev, t : ndarray (S,)
        s, start and end of each sample's interval (consecutive: ``t_prev[k] = t[k-1]``).
    wz : ndarray (S,)
        rad/s, measured yaw rates.
    var_rate : ndarray (S,)
        rad^2/s^2, their variances.
    kt : ndarray (K,)
        s, keyframe times; the samples must lie inside ``[kt[0], kt[-1]]``.

    Returns
    -------
    interval : ndarray (I,) int
        Keyframe intervals ``(kt[i], kt[i+1])`` with gyro data, increasing.
    dtheta : ndarray (I,)
        rad, integrated measured heading change.
    var : ndarray (I,)
        rad^2, its variance.
    T : ndarray (I,)
        s, duration covered (the bias coefficient).
    samples : ndarray (I,) int
        Samples ending inside each interval (each sample is counted once).
    """
    t_prev, t = np.asarray(t_prev, dtype=float), np.asarray(t, dtype=float)
    wz, var_rate = np.asarray(wz, dtype=float), np.asarray(var_rate, dtype=float)
    kt = np.asarray(kt, dtype=float)
    empty = np.zeros(0)
    if t.size == 0:
        return np.zeros(0, dtype=int), empty, empty, empty, np.zeros(0, dtype=int)
    # pieces: every sample cut at the keyframes inside it
    first = np.searchsorted(kt, t_prev, side="right")  # first keyframe after t_prev
    last = np.searchsorted(kt, t, side="left")  # first keyframe at or after t
    n_cuts = np.maximum(last - first, 0)
    reps = n_cuts + 1
    owner = np.repeat(np.arange(t.size), reps)
    j = np.arange(owner.size) - np.repeat(np.cumsum(reps) - reps, reps)
    cut_idx = np.repeat(first, reps) + j  # keyframe index that ends piece j (if a cut)
    is_last = j == np.repeat(n_cuts, reps)
    a = np.where(j == 0, t_prev[owner], kt[np.clip(cut_idx - 1, 0, kt.size - 1)])
    b = np.where(is_last, t[owner], kt[np.clip(cut_idx, 0, kt.size - 1)])
    tau = b - a
    dt = t[owner] - t_prev[owner]
    piece_interval = np.searchsorted(kt, b, side="left") - 1
    piece_interval = np.clip(piece_interval, 0, kt.size - 2)
    n_int = kt.size - 1
    dtheta = np.bincount(piece_interval, wz[owner] * tau, n_int)
    var = np.bincount(piece_interval, var_rate[owner] * dt * tau, n_int)
    T = np.bincount(piece_interval, tau, n_int)
    end_interval = np.clip(np.searchsorted(kt, t, side="left") - 1, 0, n_int - 1)
    samples = np.bincount(end_interval, minlength=n_int)
    keep = np.flatnonzero(T > 0)
    return keep, dtheta[keep], var[keep], T[keep], samples[keep]
