"""Landmark initialisation of range SLAM (``slam: true``, batch smoother only).

Owns the robust grid search that gives unknown landmarks their initial positions from the
ranges and a pose guess (:func:`slam_initial_landmarks`), and the view of a log whose map
lists every landmark id seen (:func:`log_with_ids`), from which the measurement models of a
SLAM run are built.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from odofuse.estimators.graph.keys import model_kind

if TYPE_CHECKING:  # a type only: problem.py imports this module
    from odofuse.estimators.graph.problem import GraphProblem


def log_with_ids(log):
    """A view of ``log`` whose map lists every landmark id seen (positions unused in SLAM)."""
    import dataclasses

    ids = set(log.landmarks)
    for stream in log.streams.values():
        if "id" in stream.columns:
            ids.update(int(i) for i in np.unique(stream["id"]) if np.isfinite(i))
    return dataclasses.replace(log, landmarks={i: np.zeros(2) for i in ids})


def slam_initial_landmarks(problem: GraphProblem, poses) -> dict[int, np.ndarray]:
    """Robust initial positions of unknown landmarks from ranges and a pose guess.

    For every landmark id with range rows (range or range-bearing sensors) a grid of cell
    ``slam_grid`` m over the poses' bounding box grown by the largest range is scored with a
    truncated quadratic of ``||p_k - l|| - r_k`` (truncated at 3 sigma, so multipath outliers
    and a few-percent scale error cannot pull the minimum), then refined by Gauss-Newton on the
    inliers. The range-only ring ambiguity is broken by the robot's own motion: a landmark seen
    from a 2-D path has one minimum. Bearings, when present, go through the same cost.

    Returns
    -------
    dict
        id -> ``(2,)`` world position (m).
    """
    poses = np.asarray(poses, dtype=float)
    per_id: dict[int, list[tuple[np.ndarray, float, float]]] = {}
    for meas in problem.measurements:
        if meas.landmark is None:
            continue
        m = problem.models[meas.stream]
        kind = model_kind(m)
        if kind == "BeaconRange":
            r, sigma = float(meas.row["range"]), float(m.sigma)
        elif kind == "LandmarkRangeBearing":
            r, sigma = float(meas.row["range"]), float(m.sigma)
        else:
            continue
        per_id.setdefault(meas.landmark, []).append((poses[meas.keyframe, :2], r, sigma))
    out: dict[int, np.ndarray] = {}
    cell = problem.options.slam_grid
    for lid, obs in sorted(per_id.items()):
        P = np.array([o[0] for o in obs])
        R = np.array([o[1] for o in obs])
        sig = np.array([o[2] for o in obs])
        if len(obs) > 400:  # a spread-out subsample is plenty for the grid
            pick = np.linspace(0, len(obs) - 1, 400).astype(int)
            Pg, Rg, Sg = P[pick], R[pick], sig[pick]
        else:
            Pg, Rg, Sg = P, R, sig
        lo = P.min(0) - R.max()
        hi = P.max(0) + R.max()
        gx = np.arange(lo[0], hi[0] + cell, cell)
        gy = np.arange(lo[1], hi[1] + cell, cell)
        G = np.stack(np.meshgrid(gx, gy, indexing="ij"), -1).reshape(-1, 2)
        best, best_cost = None, np.inf
        for chunk in np.array_split(np.arange(len(G)), max(1, len(G) // 4000)):
            d = np.linalg.norm(G[chunk, None, :] - Pg[None], axis=2)
            e = np.minimum(((d - Rg) / Sg) ** 2, 9.0)
            cost = e.sum(1)
            j = int(np.argmin(cost))
            if cost[j] < best_cost:
                best, best_cost = G[chunk][j].copy(), float(cost[j])
        lm = best
        for _ in range(20):  # Gauss-Newton on the 3-sigma inliers
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
        out[lid] = lm
    return out
