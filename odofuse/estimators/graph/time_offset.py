"""The time-stamp test's score in the batch smoother's own linear system.

:mod:`odofuse.status.latency` regresses an estimate's residuals on the rate of the predicted
measurement: a reading stamped ``tau`` late reads ``h(x(t - tau)) ~ h(x(t)) - tau hdot``, so
its score ``a = sum hdot^T R^-1 e`` tests ``tau = 0``. Without the estimator's system it can
only bound ``var(a)`` by ``b = sum hdot^T R^-1 hdot`` (conservative). The smoother absorbs
most of a delay into its poses (a 0.5 s shift of the ranges came out as 0.10-0.16 s in that
regression on ``benchmarks/bench_status.py``'s logs): the same score then has a variance far
below ``b``, and the test misses delays it could see.

In the smoother's whitened system at its optimum (``A``, ``b`` of
:class:`~odofuse.estimators.graph.variance.WhitenedSystem`) the offset of one stream is one
more column ``h``: each of its factors' whitened Jacobian on the keyframe pose it is attached
to (the reading's time) times the robot's body twist there (the wheels' dead reckoning,
:func:`odofuse.status.latency.dead_reckoned`; Pose2's tangent is the body frame). The
score is ``a = h^T b`` (``b`` is the whitened ``z - h(x)``), and under the model the
residuals are ``M eps`` with ``M = I - A N_0^-1 A^T``, so

    var(a) = h^T M h = h^T h - g^T N_0^-1 g,   g = A^T h,

the information left for ``tau`` once the poses and calibrations have taken what they can
explain (Rao's score test with nuisance parameters). ``a / sqrt(var(a))`` is standard
normal under the model whatever ``h`` is: the twist only sets the power, never the false-alarm
rate. A robust factor enters with its IRLS weight ``w`` in both ``A`` and ``b``, so its
score term has variance ``w^2 <= w`` times the information it is given: conservative, and a
reading beyond Tukey's threshold (``w = 0``) leaves the test, as the conservative form's
gate leaves it out. The stream's noise may be larger than its config says: the variance is
scaled by the stream's variance component (``variance_components``; the global factor on
its global path) when that is above 1.
"""

from __future__ import annotations

import numpy as np

from odofuse.estimators.graph.keys import X
from odofuse.estimators.graph.variance import one_blas_thread
from odofuse.status import latency


def columns(fac, graph, system, log, config) -> dict:
    """Per absolute stream that :func:`odofuse.status.latency.streams` tests and that has
    factors in ``graph``: its time offset's column ``h`` (m,) in ``system`` (``graph``'s
    :class:`~odofuse.estimators.graph.variance.WhitenedSystem` at the optimum) and the
    number of readings with a non-zero entry there."""
    tested = set(latency.streams(config, log))
    by_id = {id(f): meas for meas, f in fac.created if meas.stream in tested}
    if not by_id:
        return {}
    A, owner, cols = system.A, system.owner, system.cols
    start = np.searchsorted(owner, np.arange(graph.size() + 1))
    rows, pose_col, when = {}, {}, {}
    for j in range(graph.size()):
        meas = by_id.get(id(graph.at(j)))
        if meas is None or start[j] == start[j + 1]:
            continue
        rows.setdefault(meas.stream, []).append(np.arange(start[j], start[j + 1]))
        pose_col.setdefault(meas.stream, []).append(cols[int(X(meas.keyframe))][0])
        when.setdefault(meas.stream, []).append(float(log.streams[meas.stream].t[meas.index]))
    dr = latency.dead_reckoned(config, log) if rows else None
    out = {}
    for s in rows:
        r = np.concatenate(rows[s])
        size = np.array([len(x) for x in rows[s]])
        twist = np.repeat(latency.twist(dr, np.array(when[s])), size, axis=0)  # (rows, 3)
        c = np.repeat(np.array(pose_col[s]), size)[:, None] + np.arange(3)
        J = np.asarray(A[np.repeat(r, 3), c.ravel()]).reshape(-1, 3)  # whitened dh/dpose
        h = np.zeros(A.shape[0])
        h[r] = np.einsum("ij,ij->i", J, twist)
        per_reading = np.add.reduceat(np.abs(h[r]) > 0.0, np.r_[0, np.cumsum(size)[:-1]])
        out[s] = (h, int(np.count_nonzero(per_reading)))
    return out


@one_blas_thread  # SuperLU's solve: the same digits in every process (docs/batch.md)
def score(system, h) -> tuple[float, float, float]:
    """``(a, info, naive)`` of the column ``h``: the score ``h^T b``, its variance under the
    model ``h^T h - g^T N_0^-1 g`` (``g = A^T h``) and ``h^T h``."""
    g = np.asarray(system.A.T @ h, dtype=float)
    naive = float(h @ h)
    return float(h @ system.b), naive - float(g @ system.lu0.solve(g)), naive


def scores(fac, graph, system, log, config, components: dict) -> dict:
    """Per stream of :func:`columns`: ``{"n", "a", "info", "naive", "scale"}`` (readings with
    a non-zero column, :func:`score`'s three numbers, and the variance scale: the stream's
    component of the smoother's ``variance_components`` block ``components`` when above 1)."""
    out = {}
    for s, (h, n) in columns(fac, graph, system, log, config).items():
        a, info, naive = score(system, h)
        scale = max(1.0, _component(components, s))
        out[s] = {"n": n, "a": a, "info": info, "naive": naive, "scale": scale}
    return out


def _component(block: dict, stream: str) -> float:
    """The stream's variance component of the smoother's ``variance_components`` block (the
    global factor on its global path; 1 when there is none)."""
    group = (block.get("groups") or {}).get(stream) or {}
    c = group.get("variance_factor", block.get("variance_factor"))
    return float(c) if c is not None and np.isfinite(c) else 1.0
