"""Chordal initial poses of a graph with loop closures (no GTSAM objects).

Owns :func:`chordal_poses`: keyframe poses from the odometry edges and the loop closures
alone, by two sparse linear least-squares problems (the chordal relaxation of rotation
averaging, then the positions given the rotations; Carlone et al., "Initialization
techniques for 3D SLAM", ICRA 2015, section III, restricted to the plane):

1. each heading as an unconstrained 2-vector ``z_k = (cos, sin)``; every edge ``i -> j``
   with relative heading ``d`` gives ``z_j - R(d) z_i = 0`` weighted by ``1 / sigma_theta``;
   ``z_0`` is fixed at the first pose's heading; each ``z_k`` is normalised afterwards;
2. every edge gives ``t_j - t_i - R(theta_i) (dx, dy) = 0`` weighted by the inverse of its
   root-mean translation sigma; ``t_0`` is fixed at the first pose.

Dead reckoning accumulates the heading error of every step; the relaxation spreads the loop
closures' heading evidence over the whole graph in one solve, with no starting point. On
``w20000.txt`` (20,061 poses, 6,771 loop closures, heading sigma 2.24 rad) the composed
odometry starts GTSAM's LM at error 52,147,630 and it stalls above 250 after a thousand
iterations; from the chordal poses (error 76) it converges to 18.763 in about 50
(docs/graph.md, "Pose graphs and SLAM files of the wheel").
"""

from __future__ import annotations

import numpy as np


def _edges(problem):
    """``(i, j, delta (M, 3), cov (M, 3, 3))`` of the odometry chain and the loop closures."""
    K = len(problem.kt)
    i = np.arange(K - 1)
    deltas, covs = [np.asarray(problem.deltas)], [np.asarray(problem.covs)]
    li = [lp.i for lp in problem.loops]
    lj = [lp.j for lp in problem.loops]
    if problem.loops:
        deltas.append(np.array([lp.delta for lp in problem.loops], dtype=float))
        covs.append(np.array([lp.cov for lp in problem.loops], dtype=float))
    return (
        np.concatenate([i, np.array(li, dtype=int)]),
        np.concatenate([i + 1, np.array(lj, dtype=int)]),
        np.concatenate(deltas),
        np.concatenate(covs),
    )


def _solve_anchored(rows, cols, vals, rhs, n_rows, n_unknowns, fixed):
    """Weighted least squares ``A x = rhs`` with the unknowns ``fixed`` (index -> value) held.

    ``A`` is given as COO triplets; returns ``x`` ``(n_unknowns,)``.
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla

    A = sp.csr_matrix((vals, (rows, cols)), shape=(n_rows, n_unknowns))
    idx = np.fromiter(fixed, dtype=int)
    x_fixed = np.array([fixed[k] for k in idx], dtype=float)
    free = np.setdiff1d(np.arange(n_unknowns), idx)
    b = rhs - A[:, idx] @ x_fixed
    Af = A[:, free]
    x = np.empty(n_unknowns)
    x[idx] = x_fixed
    x[free] = sla.spsolve((Af.T @ Af).tocsc(), Af.T @ b)
    return x


def chordal_poses(problem) -> np.ndarray:
    """Keyframe poses ``(K, 3)`` (x, y m; theta rad, world frame) by chordal relaxation.

    Parameters
    ----------
    problem : GraphProblem
        Its odometry edges (``deltas``, ``covs``), ``loops`` and first pose ``pose0``; every
        keyframe must be reached by the odometry chain (it always is: one edge per step).

    Returns
    -------
    ndarray (K, 3)
        Headings wrapped to ``(-pi, pi]``. The other factors of the graph (priors, GPS,
        landmarks) are not used: :func:`~odofuse.estimators.graph.solvers.run_smoother`
        starts from these poses only when the graph error there is below dead reckoning's.
    """
    from odofuse import se2

    i, j, d, cov = _edges(problem)
    K, M = len(problem.kt), len(i)
    r = np.arange(M)
    w = 1.0 / np.sqrt(np.maximum(cov[:, 2, 2], 1e-300))
    c, s = np.cos(d[:, 2]), np.sin(d[:, 2])
    # z_j - R(d) z_i: real row  c_j - (c c_i - s s_i), imaginary row  s_j - (s c_i + c s_i)
    rows = np.concatenate([2 * r, 2 * r, 2 * r, 2 * r + 1, 2 * r + 1, 2 * r + 1])
    cols = np.concatenate([2 * j, 2 * i, 2 * i + 1, 2 * j + 1, 2 * i, 2 * i + 1])
    vals = np.concatenate([w, -w * c, w * s, w, -w * s, -w * c])
    th0 = float(problem.pose0[2])
    z = _solve_anchored(
        rows, cols, vals, np.zeros(2 * M), 2 * M, 2 * K, {0: np.cos(th0), 1: np.sin(th0)}
    ).reshape(K, 2)
    theta = np.arctan2(z[:, 1], z[:, 0])
    wt = 1.0 / np.sqrt(np.maximum(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]), 1e-300))
    ci, si = np.cos(theta[i]), np.sin(theta[i])
    step = (ci * d[:, 0] - si * d[:, 1], si * d[:, 0] + ci * d[:, 1])
    rows, cols, vals = np.concatenate([r, r]), np.concatenate([j, i]), np.concatenate([wt, -wt])
    xy = [
        _solve_anchored(rows, cols, vals, wt * step[a], M, K, {0: float(problem.pose0[a])})
        for a in (0, 1)
    ]
    return np.column_stack([xy[0], xy[1], se2.wrap(theta)])
