"""Trajectories and estimator results: what every estimator returns, and the block size of
every whole-run pass over them (:func:`pose_blocks`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from odofuse.se2 import wrap

#: Poses per block of a whole-run pass over per-pose arrays (metrics, covariance checks):
#: bounds the temporaries to a few MB whatever the run's length. Each value is computed pose
#: by pose, so the blocks give the same bits as one whole-array pass.
BLOCK = 1 << 16


def pose_blocks(n: int, block: int | None = None):
    """Slices of ``range(n)`` of at most ``block`` (default :data:`BLOCK`) items."""
    b = BLOCK if block is None else int(block)
    return (slice(k, min(k + b, n)) for k in range(0, n, b))


@dataclass(frozen=True)
class Trajectory:
    """A time-stamped sequence of planar poses with optional world-frame covariances.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Time stamps in seconds, non-decreasing.
    poses : ndarray, shape (N, 3)
        ``[x, y, theta]`` in the world frame (m, m, rad), theta wrapped to [-pi, pi).
    covariances : ndarray, shape (N, 3, 3), optional
        Pose covariances over ``[x, y, theta]`` in the world frame.
    """

    t: np.ndarray
    poses: np.ndarray
    covariances: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        poses = np.asarray(self.poses, dtype=float)
        if t.ndim != 1 or poses.shape != (t.size, 3):
            raise ValueError(
                f"Trajectory needs t (N,) and poses (N, 3); got {t.shape}, {poses.shape}"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "poses", poses)
        if self.covariances is not None:
            cov = np.asarray(self.covariances, dtype=float)
            if cov.shape != (t.size, 3, 3):
                raise ValueError(f"covariances must be (N, 3, 3); got {cov.shape}")
            object.__setattr__(self, "covariances", cov)

    def __len__(self) -> int:
        return self.t.size

    @property
    def xy(self) -> np.ndarray:
        """Positions, shape (N, 2)."""
        return self.poses[:, :2]


@dataclass(frozen=True)
class EstimateResult:
    """What an estimator returns: the trajectory plus bookkeeping for ``metrics.json``.

    ``used``/``rejected`` count measurements per sensor stream; ``extra`` holds estimator
    specific results (calibration estimates, landmark positions, ...), JSON-serialisable;
    ``findings`` are the estimator's own self-checks that failed (:mod:`odofuse.status.findings`),
    from which the run's ``status`` is derived.
    """

    estimator: str
    trajectory: Trajectory
    used: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    findings: tuple = ()


def bracket(tt: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear-interpolation neighbours of times ``t`` (inside the span of the sorted ``tt``,
    at least two samples): ``k`` (M,), the sample at or before each time (clipped to
    ``[0, len(tt) - 2]``), and ``a`` (M,), the weight of sample ``k + 1`` (0 across a
    zero-length interval)."""
    k = np.clip(np.searchsorted(tt, t, side="right") - 1, 0, tt.size - 2)
    dt = tt[k + 1] - tt[k]
    return k, np.where(dt > 0, (t - tt[k]) / np.where(dt > 0, dt, 1.0), 0.0)


def interpolate_poses(traj: Trajectory, t) -> np.ndarray:
    """Poses of ``traj`` at times ``t`` (inside its time span), shape (M, 3).

    Positions are interpolated linearly; headings along the shorter arc between neighbours.
    Computed in blocks of :data:`odofuse.trajectory.BLOCK` times (temporaries bounded, same values).
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    tt = traj.t
    if tt.size == 1:
        return np.repeat(traj.poses[:1], t.size, axis=0)
    out = np.empty((t.size, 3))
    for b in pose_blocks(t.size):
        k, a = bracket(tt, t[b])
        p0, p1 = traj.poses[k], traj.poses[k + 1]
        out[b, :2] = p0[:, :2] + a[:, None] * (p1[:, :2] - p0[:, :2])
        out[b, 2] = wrap(p0[:, 2] + a * wrap(p1[:, 2] - p0[:, 2]))
    return out
