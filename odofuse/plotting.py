"""Pictures of a run: estimate, ground truth, beacons/landmarks and 2-sigma covariance ellipses.

Uses matplotlib's non-interactive Agg backend through the object API (no pyplot state), so it
works on headless machines and in threads. Lines longer than :data:`MAX_LINE_POINTS` are
decimated (:func:`decimate`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse.trajectory import EstimateResult, Trajectory

#: Lines with more points than this are decimated (every k-th point and the last): at the
#: picture's 880 x 770 pixels nothing is lost, and a 10 h, 50 Hz run draws in a second.
MAX_LINE_POINTS = 50_000
#: Mahalanobis radius of the drawn ellipses: 2 sigma in 2-D holds 86.5 % of the probability.
ELLIPSE_SIGMA = 2.0


def covariance_ellipse(
    mean_xy, cov_xy, n_sigma: float = ELLIPSE_SIGMA, points: int = 64
) -> np.ndarray:
    """Outline of the ``n_sigma`` ellipse of a 2-D Gaussian.

    Parameters
    ----------
    mean_xy : array_like, shape (2,)
        Centre (m).
    cov_xy : array_like, shape (2, 2)
        Position covariance (m^2), world frame.
    n_sigma : float
        Mahalanobis radius.
    points : int
        Number of outline points.

    Returns
    -------
    ndarray, shape (points, 2)
        Points ``mean + n_sigma * V sqrt(L) [cos a, sin a]`` with ``cov = V L V^T``.
    """
    cov = 0.5 * (np.asarray(cov_xy, dtype=float) + np.asarray(cov_xy, dtype=float).T)
    w, v = np.linalg.eigh(cov)
    w = np.clip(w, 0.0, None)
    a = np.linspace(0.0, 2 * math.pi, points)
    circle = np.stack([np.cos(a), np.sin(a)], axis=1)
    return np.asarray(mean_xy, dtype=float) + n_sigma * (circle * np.sqrt(w)) @ v.T


def decimate(n: int, limit: int = MAX_LINE_POINTS) -> slice | np.ndarray:
    """Indices of the points of an ``n``-point line to draw: all of them up to ``limit``, else
    every ``ceil(n / limit)``-th point and the last."""
    if n <= limit:
        return slice(None)
    k = -(-n // limit)
    idx = np.arange(0, n, k)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def plot_run(
    out_png: str | Path,
    result: EstimateResult | Trajectory,
    log=None,
    ellipses: int = 15,
    title: str | None = None,
) -> Path:
    """Draw the estimate (and ground truth, landmarks, ellipses) into a PNG, written atomically.

    Parameters
    ----------
    out_png : str or Path
        Output file.
    result : EstimateResult or Trajectory
        The estimate.
    log : SensorLog, optional
        Ground truth (``log.groundtruth``) and landmarks (``log.landmarks``). Landmarks the
        estimator estimated (``result.extra["landmarks"]``, SLAM) are drawn beside them, with
        2-sigma ellipses from ``extra["landmark_covariances"]``.
    ellipses : int
        About this many 2-sigma position ellipses, evenly spaced along the trajectory
        (only where covariances exist).
    title : str, optional
        Defaults to the estimator name.

    Returns
    -------
    Path
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from odofuse.io.atomic import atomic_write

    traj = result.trajectory if isinstance(result, EstimateResult) else result
    name = result.estimator if isinstance(result, EstimateResult) else "estimate"
    fig = Figure(figsize=(8, 7), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    gt = getattr(log, "groundtruth", None)
    if gt is not None and len(gt):
        keep = decimate(len(gt))
        ax.plot(gt["x"][keep], gt["y"][keep], color="0.45", lw=1.2, label="ground truth")
    keep = decimate(len(traj))
    ax.plot(
        traj.poses[keep, 0],
        traj.poses[keep, 1],
        color="tab:blue",
        lw=1.2,
        label=f"{name} estimate",
    )
    if len(traj):
        ax.plot(*traj.poses[0, :2], "o", color="tab:green", ms=6, label="start")
        ax.plot(*traj.poses[-1, :2], "s", color="tab:red", ms=6, label="end")
    if traj.covariances is not None and ellipses > 0 and len(traj):
        step = max(1, len(traj) // ellipses)
        first = True
        for k in range(0, len(traj), step):
            cov = traj.covariances[k, :2, :2]
            if not np.all(np.isfinite(cov)):
                continue
            e = covariance_ellipse(traj.poses[k, :2], cov)
            ax.plot(
                e[:, 0],
                e[:, 1],
                color="tab:orange",
                lw=0.8,
                alpha=0.8,
                label=f"{ELLIPSE_SIGMA:g}-sigma position ellipse" if first else None,
            )
            first = False
    landmarks = getattr(log, "landmarks", None) or {}
    if landmarks:
        ids = sorted(landmarks)
        pts = np.array([landmarks[i] for i in ids])
        ax.plot(pts[:, 0], pts[:, 1], "^", color="k", ms=8, label="beacons / landmarks")
        for i, p in zip(ids, pts, strict=False):
            ax.annotate(str(i), p, textcoords="offset points", xytext=(5, 5), fontsize=8)
    estimated = result.extra.get("landmarks") if isinstance(result, EstimateResult) else None
    if estimated:
        ids = sorted(estimated, key=int)
        pts = np.array([estimated[i] for i in ids], dtype=float)
        ax.plot(pts[:, 0], pts[:, 1], "+", color="tab:purple", ms=8, label="estimated landmarks")
        covs = result.extra.get("landmark_covariances") or {}
        for i, p in zip(ids, pts, strict=True):
            if i in covs and np.all(np.isfinite(covs[i])):
                vx, cxy, vy = covs[i]
                e = covariance_ellipse(p, [[vx, cxy], [cxy, vy]])
                ax.plot(e[:, 0], e[:, 1], color="tab:purple", lw=0.6, alpha=0.7)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.4, alpha=0.6)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or f"odofuse: {name}")
    # fixed margins (room for 8-character tick labels): tight_layout measured every text
    # box first, 0.17 of the 0.25 s a plot took (four plots in the README's first command)
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.08, top=0.95)
    return atomic_write(out_png, lambda tmp: fig.savefig(tmp, format="png"))
