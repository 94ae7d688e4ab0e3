"""Keyframes and odometry pre-integration of the graph (no GTSAM objects).

Owns where keyframes fall (:func:`keyframe_times`: the odometry span's ends, sensor times
and the dt / ds / dtheta triggers) and the relative pose, body-frame covariance and
calibration sensitivity of the odometry between consecutive keyframes (:func:`preintegrate`,
``MotionModel.relative`` vectorised over all intervals); an odometry step straddling a
keyframe is split, its wheel / increment inputs scaled by the time fraction. Also the
high-rate sensors attached to keyframes instead of making their own: gyro samples summed per
keyframe interval (:func:`preintegrate_gyro`) and absolute heading readings moved to their
nearest keyframe through the rotation since it (gyro or wheels) and averaged
(:func:`attach_headings`).
"""

from __future__ import annotations

import numpy as np

from odofuse import se2
from odofuse.declarations import GraphOptions

#: Keyframe times closer than this (s) are merged (:func:`keyframe_times`).
MERGE_TOLERANCE = 1e-9


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
        Strictly increasing keyframe times (s). Times closer than :data:`MERGE_TOLERANCE`
        (or 16 floating-point spacings of their magnitude) are one keyframe, the latest of
        them, so that ``searchsorted(kt, t)`` of any of them finds it: a ``keyframe_dt``
        grid from ``t0 = 4e-16`` put 1.0000000000000004 beside a GPS fix at 1.0, and the
        4e-16 s interval between them (odometry and gyro variances ~0) left the smoother's
        Levenberg-Marquardt at its iteration cap on every such log.
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
    kt = np.unique(np.concatenate(parts))
    tol = np.maximum(MERGE_TOLERANCE, 16.0 * np.spacing(np.abs(kt[1:])))
    return kt[np.append(np.diff(kt) > tol, True)]


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


def gyro_rotation_track(t_prev, t, wz, var_rate, bias=0.0):
    """Heading rotated since the first gyro sample, and its variance, at the sample ends.

    The same piece model as :func:`preintegrate_gyro`: inside sample ``k`` the rotation grows
    linearly by ``(wz[k] - bias) tau`` and its variance by ``var_rate[k] dt tau``, so linear
    interpolation of the returned knots (:func:`attach_headings`) gives the rotation between
    any two times of the stream's span.

    Parameters
    ----------
    t_prev, t : ndarray (S,)
        s, start and end of each (consecutive) sample's interval.
    wz, var_rate : ndarray (S,)
        rad/s and rad^2/s^2, measured yaw rates and their variances.
    bias : float
        rad/s, the bias subtracted (the prior value of ``gyro_bias``).

    Returns
    -------
    knots : ndarray (S+1,)
        s, ``t_prev[0]`` then ``t``.
    theta, var : ndarray (S+1,)
        rad and rad^2, cumulative rotation and variance at the knots (0 at the first).
    """
    t_prev, t = np.asarray(t_prev, dtype=float), np.asarray(t, dtype=float)
    dt = t - t_prev
    theta = np.concatenate([[0.0], np.cumsum((np.asarray(wz, dtype=float) - bias) * dt)])
    var = np.concatenate([[0.0], np.cumsum(np.asarray(var_rate, dtype=float) * dt * dt)])
    return np.concatenate([t_prev[:1], t]), theta, var


def wheel_rotation_track(t_odo, U, model):
    """Heading rotated by the odometry since ``t_odo[0]`` and its variance, per odometry pose.

    Step ``k``'s heading change ``dtheta`` and its variance ``J_theta diag(var_u) J_theta^T``
    (``MotionModel`` increment and error model, nominal calibration), accumulated; inside a
    step both grow linearly in time (the time-fraction split of :func:`preintegrate`).

    Returns
    -------
    knots : ndarray (N+1,)
        s, ``t_odo``.
    theta, var : ndarray (N+1,)
        rad and rad^2, cumulative at the knots.
    """
    t_odo = np.asarray(t_odo, dtype=float)
    if len(U) == 0:
        return t_odo, np.zeros(t_odo.size), np.zeros(t_odo.size)
    inc, J = model.increment(U)
    var_u = model.errors.variances(model.drive, U)
    var = np.einsum("pk,pk->p", J[:, 2, :] ** 2, var_u)
    return (
        t_odo,
        np.concatenate([[0.0], np.cumsum(inc[:, 2])]),
        np.concatenate([[0.0], np.cumsum(var)]),
    )


def attach_headings(t, heading, var, kt, tracks):
    """Absolute heading readings moved to their nearest keyframe and averaged per keyframe.

    Reading ``r`` at ``t[r]`` becomes a reading of the heading at its nearest keyframe
    ``t_k``: ``z'_r = heading[r] - (Theta(t[r]) - Theta(t_k))`` with ``Theta`` the rotation of
    the first track (gyro, then wheels) whose span holds both times. The readings of one
    keyframe are averaged with weights ``w_r ∝ 1/var[r]``; the variance of that mean is exact
    for the model (independent reading noise, white rotation-rate noise)::

        var = sum_r w_r^2 var[r] + sum_rs w_r w_s C_rs + s_b^2 (sum_r w_r (t[r] - t_k))^2

    with ``C_rs = min(|V_r|, |V_s|)`` for two readings on the same side of ``t_k`` taken from
    the same track (their rotations share the noise up to the nearer one), else 0, where
    ``V_r = V(t[r]) - V(t_k)`` is the track's rotation variance; and ``s_b`` the track's rate
    bias uncertainty (rad/s: the gyro bias prior sigma; 0 for the wheels), common to the
    readings of a keyframe (summed per track when a keyframe's readings use two). Not
    modelled: the reuse of the same gyro / wheel data by the between-keyframe factors (the
    rotations used here span at most half a keyframe interval).

    Parameters
    ----------
    t, heading, var : ndarray (R,)
        s, rad, rad^2: reading times (inside ``[kt[0], kt[-1]]``), headings and variances.
    kt : ndarray (K,)
        s, keyframe times.
    tracks : list of (knots, theta, var, bias_sigma)
        Rotation tracks (:func:`gyro_rotation_track`, :func:`wheel_rotation_track`) in order
        of preference; the last one should span ``kt``.

    Returns
    -------
    keyframe : ndarray (F,) int
        Keyframe of each averaged reading, increasing.
    heading : ndarray (F,)
        rad, wrapped.
    var : ndarray (F,)
        rad^2.
    count : ndarray (F,) int
        Readings averaged.
    first, last : ndarray (F,) int
        Index (into ``t``) of the first and the last reading of each keyframe (in the order
        of ``t``: earliest and latest when ``t`` is sorted).
    """
    t = np.asarray(t, dtype=float)
    z = np.asarray(heading, dtype=float)
    var = np.asarray(var, dtype=float)
    kt = np.asarray(kt, dtype=float)
    hi = np.clip(np.searchsorted(kt, t), 1, kt.size - 1)
    kf = np.where(t - kt[hi - 1] <= kt[hi] - t, hi - 1, hi)
    tk = kt[kf]
    source = np.full(t.size, -1)
    rot = np.zeros(t.size)
    rvar = np.zeros(t.size)
    sb = np.zeros(t.size)
    for n, (knots, theta, v, bias_sigma) in enumerate(tracks):
        lo_t, hi_t = float(knots[0]), float(knots[-1])
        use = (source < 0) & (np.minimum(t, tk) >= lo_t) & (np.maximum(t, tk) <= hi_t)
        rot[use] = np.interp(t[use], knots, theta) - np.interp(tk[use], knots, theta)
        rvar[use] = np.interp(t[use], knots, v) - np.interp(tk[use], knots, v)
        sb[use] = bias_sigma
        source[use] = n
    if np.any(source < 0):
        raise ValueError("attach_headings: a reading outside every rotation track")
    zp = z - rot
    order = np.argsort(kf, kind="stable")
    keys, first_pos, count = np.unique(kf[order], return_index=True, return_counts=True)
    out_z, out_var = np.zeros(keys.size), np.zeros(keys.size)
    for n, (a, c) in enumerate(zip(first_pos, count, strict=True)):
        idx = order[a : a + c]
        w = 1.0 / var[idx]
        w /= w.sum()
        d = se2.wrap(zp[idx] - zp[idx[0]])
        out_z[n] = se2.wrap(zp[idx[0]] + np.dot(w, d))
        side = np.sign(t[idx] - tk[idx]) + 3 * source[idx]
        same = side[:, None] == side[None, :]
        a_abs = np.abs(rvar[idx])
        C = np.where(same, np.minimum(a_abs[:, None], a_abs[None, :]), 0.0)
        wtau = w * (t[idx] - tk[idx])  # a bias error b of a track shifts z' by b tau
        bias_var = sum(
            (sb[idx][source[idx] == s][0] * wtau[source[idx] == s].sum()) ** 2
            for s in np.unique(source[idx])
        )
        out_var[n] = np.dot(w * w, var[idx]) + w @ C @ w + bias_var
    return keys, out_z, out_var, count, order[first_pos], order[first_pos + count - 1]
