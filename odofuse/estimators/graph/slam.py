"""Landmark initialisation of SLAM (``slam: true``: smoother and iSAM2).

Owns which initialisation each unknown landmark gets from a pose guess
(:func:`slam_initial_landmarks`: its first range-bearing sighting, else multilateration of its
ranges, else the robust grid search :func:`grid_search`), and the view of a log whose map
lists every landmark id seen (:func:`log_with_ids`), from which the measurement models of a
SLAM run are built. The closed-form initialisations are in
:mod:`odofuse.estimators.graph.landmarks`.
"""

from __future__ import annotations

import numpy as np

from odofuse.estimators.graph.keys import model_kind
from odofuse.estimators.graph.landmarks import from_sighting, multilaterate, refine

#: The grid search uses at most this many cells along each axis (its cell grows beyond
#: ``slam_grid`` for ranges of hundreds of metres, e.g. the acoustic ranges of GOATS).
MAX_CELLS_PER_SIDE = 400


def log_with_ids(log):
    """A view of ``log`` whose map lists every landmark id seen (positions unused in SLAM)."""
    import dataclasses

    ids = set(log.landmarks)
    for stream in log.streams.values():
        if "id" in stream.columns:
            ids.update(int(i) for i in np.unique(stream["id"]) if np.isfinite(i))
    return dataclasses.replace(log, landmarks={i: np.zeros(2) for i in ids})


def slam_initial_landmarks(measurements, models, poses, cell: float) -> dict[int, np.ndarray]:
    """Initial positions of unknown landmarks from their measurements and a pose guess.

    A landmark with a range-bearing sighting starts where its first sighting places it off
    the guessed pose (:func:`~odofuse.estimators.graph.landmarks.from_sighting`). A landmark
    seen by ranges only is multilaterated over all its ranges
    (:func:`~odofuse.estimators.graph.landmarks.multilaterate`); where that refuses (a path
    too straight, mostly outliers) the grid search :func:`grid_search` is used.

    Parameters
    ----------
    measurements : list of Measurement
        The sensor rows of a :class:`~odofuse.estimators.graph.problem.GraphProblem` (their
        ``landmark``, ``keyframe``, ``stream`` and ``row``).
    models : dict
        Stream -> measurement model.
    poses : ndarray (K, 3)
        A guess of the keyframe poses (dead reckoning, or the current estimate).
    cell : float
        m, the grid search's cell (``options.slam_grid``).

    Returns
    -------
    dict
        id -> ``(2,)`` world position (m).
    """
    poses = np.asarray(poses, dtype=float)
    per_id: dict[int, list[tuple[np.ndarray, float, float]]] = {}
    out: dict[int, np.ndarray] = {}
    for meas in measurements:
        if meas.landmark is None:
            continue
        m = models[meas.stream]
        kind = model_kind(m)
        if kind == "LandmarkRangeBearing" and meas.landmark not in out:
            pose = poses[meas.keyframe]
            out[meas.landmark] = from_sighting(pose, meas.row["range"], meas.row["bearing"])
        if kind in ("BeaconRange", "LandmarkRangeBearing"):
            sigma = float(np.sqrt(m.R(meas.row)[0, 0]))
            obs = (poses[meas.keyframe, :2], float(meas.row["range"]), sigma)
            per_id.setdefault(meas.landmark, []).append(obs)
    for lid, obs in sorted(per_id.items()):
        if lid in out:
            continue
        P = np.array([o[0] for o in obs])
        R = np.array([o[1] for o in obs])
        sig = np.array([o[2] for o in obs])
        lm = multilaterate(P, R, sig)
        out[lid] = grid_search(P, R, sig, cell) if lm is None else lm
    return out


def grid_search(P, R, sig, cell: float) -> np.ndarray:
    """Robust landmark position from ranges ``R`` (m, sigmas ``sig``) taken at ``P`` ``(n, 2)``.

    A grid of cell ``cell`` m (coarser when it would exceed :data:`MAX_CELLS_PER_SIDE`)
    over the positions' bounding box grown by the largest range is scored with a truncated
    quadratic of ``||p_k - l|| - r_k`` (truncated at 3 sigma, so multipath outliers and a
    few-percent scale error cannot pull the minimum), then refined by Gauss-Newton on the
    inliers. The range-only ring ambiguity is broken by the robot's own
    motion: a landmark seen from a 2-D path has one minimum.
    """
    if len(P) > 400:  # a spread-out subsample is plenty for the grid
        pick = np.linspace(0, len(P) - 1, 400).astype(int)
        Pg, Rg, Sg = P[pick], R[pick], sig[pick]
    else:
        Pg, Rg, Sg = P, R, sig
    lo = P.min(0) - R.max()
    hi = P.max(0) + R.max()
    cell = max(cell, float((hi - lo).max()) / MAX_CELLS_PER_SIDE)  # km-scale ranges: coarser
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
    return refine(best, P, R, sig)[0]
