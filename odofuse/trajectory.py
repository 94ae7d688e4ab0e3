"""Trajectories and estimator results: what every estimator returns, and the block size of
every whole-run pass over them (:func:`pose_blocks`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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
    ``findings`` are the estimator's own self-checks that failed (:mod:`odofuse.health`),
    from which the run's ``status`` is derived.
    """

    estimator: str
    trajectory: Trajectory
    used: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    findings: tuple = ()
