"""Relative-pose edges of a log: loop closures, and the odometry edges of pose-graph files.

Owns (no GTSAM objects):

* the ``sensors.loop_closures`` block (:func:`loop_block`: ``sigma``, ``robust``);
* :func:`file_odometry`: the odometry of a pose-graph log (``odometry`` rows carrying
  ``dx, dy`` and the ``cov_*`` columns of ``odofuse.io.posegraph``) taken as stored, one
  keyframe per pose, each edge with the file's own covariance (a row without one falls back
  to the motion model's pre-integration of its ``ds, dtheta``);
* :func:`loop_closures`: the ``loop_closures`` rows as :class:`Loop` records between two
  keyframes, with the file's covariance or the config's ``sigma``, and the rows refused
  (an end outside the odometry span or not at a keyframe, and for the fixed-lag smoother an
  earlier end older than the window);
* :func:`oldest_referenced`: for an incremental solver, the oldest keyframe that a factor
  still to come refers to (which iSAM2's keyframe window must keep).

The covariances are of ``(dx, dy, dtheta)`` in the ``to`` pose's tangent space, the frame
``BetweenFactorPose2`` uses (docs/formats.md section 3), so they go into the factor unchanged.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: The stream of loop closures (spec section 1) and the keys of its sensor block.
STREAM = "loop_closures"
COV_COLUMNS = ("cov_xx", "cov_xy", "cov_xt", "cov_yy", "cov_yt", "cov_tt")
_TRIU = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


@dataclass(frozen=True)
class Loop:
    """One loop closure ``p_i^-1 p_j = delta`` between keyframes ``i`` and ``j``.

    Attributes
    ----------
    i, j : int
        Keyframe indices of the ``from`` and ``to`` poses.
    delta : tuple
        ``(dx, dy, dtheta)``, m and rad, in the frame of pose ``i``.
    cov : ndarray (3, 3)
        Covariance in the tangent space of pose ``j`` (GTSAM's ``BetweenFactorPose2``).
    row : int
        Row of the ``loop_closures`` stream.
    """

    i: int
    j: int
    delta: tuple
    cov: np.ndarray
    row: int

    @property
    def later(self) -> int:
        """The keyframe at which an incremental solver adds the factor."""
        return max(self.i, self.j)


def loop_block(config) -> dict | None:
    """The validated ``sensors.loop_closures`` block, or ``None`` when loop closures are off.

    ``sigma``: one number (every axis, m and rad) or three ``[x, y, theta]``; it replaces the
    file's covariance by ``diag(sigma^2)``. ``robust`` is read with the other streams'
    losses by :meth:`odofuse.declarations.GraphOptions.for_run`.

    The block is validated with the config (:class:`odofuse.declarations.LoopClosureOptions`).
    """
    block = (getattr(config, "sensors", {}) or {}).get(STREAM)
    if block is None:
        return None
    out = {}
    if block.sigma is not None:
        sig = list(block.sigma) if isinstance(block.sigma, tuple) else [block.sigma]
        out["sigma"] = np.array(sig * 3 if len(sig) == 1 else sig)
    return out


def _covariances(stream) -> np.ndarray:
    """``(N, 3, 3)`` covariances from the ``cov_*`` columns (NaN where a row has none)."""
    e = np.column_stack([stream[c] for c in COV_COLUMNS])
    m = np.empty((len(e), 3, 3))
    for k, (r, c) in enumerate(_TRIU):
        m[:, r, c] = m[:, c, r] = e[:, k]
    return m


def is_pose_graph(log, stream_name: str) -> bool:
    """Whether the odometry stream holds pose-graph edges (``dx, dy, dtheta`` and ``cov_*``)."""
    s = log.streams.get(stream_name)
    return s is not None and {"dx", "dy", "dtheta", *COV_COLUMNS} <= set(s.columns)


def first_pose_time(log, t_odo: np.ndarray) -> float:
    """Time of a pose-graph log's first pose.

    Pose ``k`` is stamped ``t = k`` and odometry rows at their later pose, so the first pose
    is before the first row; a loop closure or sighting from an earlier time names it (the
    first id of the chain). Without one, the nominal period before the first row.
    """
    first = float(t_odo[1])
    earlier = [float(t) for t in loop_times(log) if t < first]
    for s in log.streams.values():
        if s.name not in (STREAM, "odometry") and len(s) and s.t.min() < first:
            earlier.append(float(s.t.min()))
    return min(earlier) if earlier else float(t_odo[0])


def file_odometry(log, stream_name: str, t_odo: np.ndarray, model):
    """Keyframes and odometry factors of a pose-graph log, as stored in the file.

    Parameters
    ----------
    log : SensorLog
    stream_name : str
        The odometry stream (``"odometry"``).
    t_odo : ndarray (N+1,)
        Pose times from :func:`odometry_inputs` (the first is replaced by
        :func:`first_pose_time`).
    model : MotionModel
        For the rows without a covariance: ``model.relative`` of their ``ds, dtheta``.

    Returns
    -------
    kt : ndarray (N+1,)
        One keyframe per pose (s).
    deltas : ndarray (N, 3)
        ``(dx, dy, dtheta)`` of each edge.
    covs : ndarray (N, 3, 3)
        The file's covariance per edge (GTSAM tangent convention).
    """
    s = log.streams[stream_name]
    kt = np.asarray(t_odo, dtype=float).copy()
    kt[0] = first_pose_time(log, kt)
    deltas = np.column_stack([s["dx"], s["dy"], s["dtheta"]])
    covs = _covariances(s)
    missing = ~np.isfinite(covs).all(axis=(1, 2))
    if missing.any():
        from odofuse.estimators.graph.keyframes import preintegrate

        U = np.column_stack([s[c] for c in model.drive.input_names])
        _, model_covs = preintegrate(kt, U, model, kt)
        covs[missing] = model_covs[missing]
    return kt, deltas, covs


def loop_times(log) -> np.ndarray:
    """Times of both ends of every loop closure (keyframes are placed there)."""
    lc = log.streams.get(STREAM)
    if lc is None or not len(lc):
        return np.empty(0)
    return np.concatenate([lc["t_from"], lc["t_to"]])


def loop_closures(log, block: dict, kt: np.ndarray, lag: float | None = None):
    """Loop closures of ``log`` between the keyframes ``kt``.

    Parameters
    ----------
    log : SensorLog
    block : dict
        From :func:`loop_block` (``sigma`` overrides the file's covariance).
    kt : ndarray (K,)
        Keyframe times (s).
    lag : float, optional
        s, the fixed-lag window: a loop whose earlier end is more than ``lag`` before its
        later end would reach a marginalised pose, so it is refused.

    Returns
    -------
    loops : list of Loop
    rejected : int
        Rows refused (an end not at a keyframe, outside the window, or without covariance
        and without a config ``sigma``).
    """
    lc = log.streams.get(STREAM)
    if lc is None or not len(lc):
        return [], 0
    covs = _covariances(lc)
    if "sigma" in block:
        covs[:] = np.diag(block["sigma"] ** 2)
    tol = 1e-9 * max(1.0, float(np.abs(kt).max()))

    def keyframe_of(t):  # index of the keyframe at each time, -1 where there is none
        k = np.minimum(np.searchsorted(kt, t - tol), len(kt) - 1)
        return np.where(np.abs(kt[k] - t) <= tol, k, -1)

    i, j = keyframe_of(lc["t_from"]), keyframe_of(lc["t_to"])
    ok = (i >= 0) & (j >= 0) & (i != j) & np.isfinite(covs).all(axis=(1, 2))
    if lag is not None:
        ok &= kt[np.minimum(i, j)] >= kt[np.maximum(i, j)] - lag
    d = np.column_stack([lc["dx"], lc["dy"], lc["dtheta"]])
    loops = [
        Loop(int(i[r]), int(j[r]), tuple(float(x) for x in d[r]), covs[r], int(r))
        for r in np.flatnonzero(ok)
    ]
    return loops, int((~ok).sum())


def oldest_referenced(pairs) -> Callable[[int], int | None]:
    """``i -> `` the oldest keyframe that a factor added after keyframe ``i`` refers to.

    Parameters
    ----------
    pairs : iterable of (int, int)
        ``(later, earliest)`` per factor: added with keyframe ``later``, it refers to keyframe
        ``earliest`` (a loop closure's ``(later, min(i, j))``).

    Returns
    -------
    callable
        ``None`` when no factor comes after ``i``.
    """
    pairs = sorted((int(a), int(b)) for a, b in pairs)
    later = [a for a, _ in pairs]
    hold = [int(x) for x in np.minimum.accumulate([b for _, b in pairs][::-1])[::-1]] + [None]
    return lambda i: hold[bisect.bisect_right(later, i)]
