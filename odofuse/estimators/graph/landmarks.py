"""Initial positions of unknown landmarks from a pose guess (no GTSAM objects).

Owns the two closed-form initialisations SLAM tries before the grid search of
:mod:`odofuse.estimators.graph.slam`:

* :func:`from_sighting`: a range-bearing sighting placed off the pose that made it
  (``l = p + r [cos(theta + b), sin(theta + b)]``), as GTSAM's own ``load2D`` initialises
  the landmarks of a bearing-range dataset;
* :func:`multilaterate`: linear least squares of ``||p_k - l||^2 = r_k^2`` over several
  ranges (the mean equation subtracted, which removes ``||l||^2``), then Cauchy-weighted
  Gauss-Newton on the ranges themselves and Gauss-Newton on their 3-sigma inliers. It
  refuses (returns ``None``) when the poses do not span two dimensions (a straight path
  leaves the mirror image equally good) or when fewer than half the ranges end up inliers,
  and the caller falls back to the grid search.
"""

from __future__ import annotations

import math

import numpy as np

#: Smallest spread (m, RMS about the centroid along the poses' thinnest direction) for which
#: the ranges fix a landmark without a mirror ambiguity.
MIN_SPREAD = 0.5
#: Fraction of ranges that must be 3-sigma inliers at the multilaterated position.
MIN_INLIERS = 0.5


def from_sighting(pose, rng: float, bearing: float) -> np.ndarray:
    """World position ``(2,)`` of a landmark seen at ``rng`` (m), ``bearing`` (rad, robot
    frame) from ``pose = (x, y, theta)``."""
    a = float(pose[2]) + float(bearing)
    return np.array([pose[0] + rng * math.cos(a), pose[1] + rng * math.sin(a)])


def refine(lm, P, R, sig, iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on the 3-sigma inliers of ``||P_k - l|| = R_k``.

    Returns the position ``(2,)`` and the inlier mask ``(n,)`` at it.
    """
    lm = np.asarray(lm, dtype=float)
    inl = np.ones(len(P), bool)
    for _ in range(iterations):
        diff = lm - P
        d = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
        e = (d - R) / sig
        inl = np.abs(e) < 3.0
        if inl.sum() < 3:
            break
        J = diff[inl] / d[inl, None] / sig[inl, None]
        step = np.linalg.lstsq(J, -e[inl], rcond=None)[0]
        lm = lm + step
        if np.linalg.norm(step) < 1e-6:
            break
    d = np.linalg.norm(lm - P, axis=1)
    return lm, np.abs((d - R) / sig) < 3.0


def multilaterate(P, R, sig) -> np.ndarray | None:
    """Landmark position ``(2,)`` from ranges ``R`` (m, sigmas ``sig``) taken at positions
    ``P`` ``(n, 2)``, or ``None`` when the geometry or the data do not fix it (module docstring).
    """
    P, R, sig = (np.asarray(a, dtype=float) for a in (P, R, sig))
    if len(P) < 3:
        return None
    c = P.mean(axis=0)
    Q = P - c
    if np.linalg.svd(Q, compute_uv=False)[-1] / math.sqrt(len(P)) < MIN_SPREAD:
        return None
    # ||q_k||^2 - 2 q_k.m + ||m||^2 = r_k^2 with m = l - c; minus the mean equation:
    A = -2.0 * Q
    q2 = np.sum(Q * Q, axis=1)
    b = (R**2 - np.mean(R**2)) - (q2 - np.mean(q2))
    lm = c + np.linalg.lstsq(A, b, rcond=None)[0]
    # the squared ranges weigh outliers heavily: Cauchy-weighted Gauss-Newton on the ranges,
    # scale from the residuals' MAD (never below 3 sigma), before the 3-sigma refinement
    for _ in range(30):
        diff = lm - P
        d = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
        e = d - R
        scale = max(
            1.4826 * float(np.median(np.abs(e - np.median(e)))), 3.0 * float(np.median(sig))
        )
        w = np.sqrt(1.0 / (1.0 + (e / scale) ** 2))
        step = np.linalg.lstsq(diff / d[:, None] * w[:, None], -e * w, rcond=None)[0]
        lm = lm + step
        if np.linalg.norm(step) < 1e-6:
            break
    lm, inl = refine(lm, P, R, sig)
    if inl.mean() < MIN_INLIERS or not np.all(np.isfinite(lm)):
        return None
    return lm
