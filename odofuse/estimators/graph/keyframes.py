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
from odofuse.estimators.graph.options import GraphOptions


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
