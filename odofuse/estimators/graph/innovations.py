"""Predicted innovations of an incremental graph: the filters' NIS, for fixed-lag and iSAM2.

Before keyframe ``i``'s factors go into the smoother, each of its sensor rows is tested
against the prediction that everything before it makes: the smoother's joint marginal of the
old variables the keyframe's factors touch (the last pose, the calibration vectors, a
landmark), carried to the new variables by the keyframe's other factors (odometry, gyro, a
walking bias's step, a pinned beacon copy). With the sensor row's factor whitened by its
Gaussian noise (robust loss removed), ``A delta - b``, the innovation is ``y = b - A mu`` and
its covariance ``S = A P A^T + I`` (``mu``, ``P``: the prediction's mean and covariance in the
tangent space at the smoother's estimate), and ``NIS = y^T S^-1 y`` is chi-square with the
row's dimension when the smoother's covariance is honest: the statistic a filter's gate and
NIS windows test (docs/trust.md, "The promise"). The rows of one keyframe are each tested
against the same prediction, so each is chi-square on its own (a filter tests them in turn).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from odofuse.declarations import FilterOptions
from odofuse.estimators.graph.keys import is_vector

#: The fixed-lag smoother's and iSAM2's NIS checks run at the filters' defaults (window,
#: ``nis_alpha``, persistence, hysteresis, ``reject_run``), without the filters' recovery
#: (an inflated covariance): fixed-lag re-admits a gated stream's rows instead
#: (:func:`gated_out`), iSAM2 solves with the configured losses at the end.
#: ``cross_check.alpha_budget`` counts them at this ``nis_alpha``.
NIS_OPTIONS = dataclasses.replace(FilterOptions(), recovery=False)


def _jacobian(lin, index: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A linearised factor's whitened Jacobian on the stacked tangent vector, and its ``b``."""
    A, b = lin.jacobian()
    out = np.zeros((A.shape[0], n))
    col = 0
    for k in lin.keys():
        start, dim = index[k]
        out[:, start : start + dim] = A[:, col : col + dim]
        col += dim
    return out, np.asarray(b, dtype=float)


def current_values(isam, keys, known=None):
    """iSAM2's current estimate of ``keys`` (``gtsam.Values``) without bringing its whole
    delta up to date, as ``calculateEstimate`` does at O(n) a call (``tests/test_graph.py``):
    each key's linearisation point moved by the mean of its marginal (``marginalFactor``,
    the solution of iSAM2's linear system at that key), as
    :func:`odofuse.estimators.graph.isam2._newest_estimate` reads the newest pose: iSAM2's
    ``calculateBestEstimate`` at those keys. Keys are poses ``x``, calibration vectors ``c``,
    ``o``, ``w`` or points (:mod:`odofuse.estimators.graph.keys`). Where a key's marginal is
    indeterminate for GTSAM's Cholesky (a calibration vector before the readings fix it,
    beside landmarks pinned at 1e-6 m: 6 of 3,526 reads on Plaza1, all at the start), the
    whole estimate (``calculateEstimate``) is returned instead. ``known`` (key -> pose) gives
    poses already read this way since iSAM2's last update (the newest pose, which
    ``_newest_estimate`` read right after it), so that each marginal is read once."""
    import gtsam

    lin = isam.getLinearizationPoint()
    none = gtsam.VectorValues()
    out = gtsam.Values()
    for k in keys:
        if known is not None and k in known:
            out.insert(k, known[k])
            continue
        try:
            step = isam.marginalFactor(k).solve(none).at(k)
        except RuntimeError:  # indeterminate for Cholesky: the whole estimate, once
            return isam.calculateEstimate()
        if gtsam.Symbol(k).chr() == ord("x"):
            out.insert(k, lin.atPose2(k).retract(step))
        elif is_vector(k):
            out.insert(k, lin.atVector(k) + step)
        else:
            out.insert(k, gtsam.Point2(*(np.asarray(lin.atPoint2(k)) + step)))
    return out


def predicted_nis(isam, graph, new_values, rows: dict, dims: dict, read=None) -> dict:
    """NIS of one keyframe's sensor factors against the smoother's prediction.

    Parameters
    ----------
    isam : gtsam.ISAM2
        The smoother's iSAM2, before the keyframe's update.
    graph : gtsam.NonlinearFactorGraph
        The keyframe's factors.
    new_values : gtsam.Values
        The keyframe's new variables at their predicted values.
    rows : dict
        Position in ``graph`` of each sensor factor to test -> the same factor with its
        Gaussian noise only (no robust loss). The other factors of ``graph`` make the
        prediction.
    dims : dict
        Key -> tangent dimension of every variable of ``graph``.
    read : callable, optional
        ``read(isam, keys)``: the estimate of the old ``keys`` (:func:`current_values` for
        iSAM2); None reads ``isam.calculateEstimate()`` (the fixed-lag window's, bounded).

    Returns
    -------
    dict
        Position -> ``(NIS, whitened innovation)`` (``status.streaming.whiten`` of the
        noise-whitened innovation and its covariance, for the innovation-mean scan); empty
        when a factor refers to a variable that neither the smoother nor ``new_values`` holds
        (nothing predicts it), ``(nan, None)`` where the prediction's covariance is not
        positive definite.
    """
    from odofuse.status.streaming import whiten

    keys = sorted({k for j in range(graph.size()) for k in graph.at(j).keys()})
    new = set(new_values.keys())
    old = [k for k in keys if k not in new]
    if not all(isam.valueExists(k) for k in old):
        return {}
    index, n = {}, 0
    for k in old + [k for k in keys if k in new]:
        index[k] = (n, int(dims[k]))
        n += int(dims[k])
    values = isam.calculateEstimate() if read is None else read(isam, old)
    values.insert(new_values)
    info = np.zeros((n, n))
    eta = np.zeros(n)
    m = sum(int(dims[k]) for k in old)
    try:
        if old:
            cov = np.asarray(isam.jointMarginalCovariance(old).fullMatrix(), dtype=float)
            info[:m, :m] = np.linalg.inv(cov)
        for j in range(graph.size()):
            if j not in rows:
                A, b = _jacobian(graph.at(j).linearize(values), index, n)
                info += A.T @ A
                eta += A.T @ b
        chol = np.linalg.cholesky(info)
    except (np.linalg.LinAlgError, RuntimeError):
        return {j: (math.nan, None) for j in rows}
    mu = np.linalg.solve(chol.T, np.linalg.solve(chol, eta))
    out = {}
    for j, f in rows.items():
        A, b = _jacobian(f.linearize(values), index, n)
        half = np.linalg.solve(chol, A.T)  # P = L^-T L^-1, so A P A^T = half^T half
        S = half.T @ half + np.eye(A.shape[0])
        y = b - A @ mu
        out[j] = float(y @ np.linalg.solve(S, y)), whiten(y, S)
    return out


def monitor(problem):
    """The filters' streaming NIS checks (:class:`~odofuse.status.monitors.FilterMonitor`)
    for the sensor streams of ``problem``, with :data:`NIS_OPTIONS`."""
    from odofuse.status.monitors import FilterMonitor

    return FilterMonitor(NIS_OPTIONS, problem.models)


def observe(mon, isam, fac, graph, new_values, read=None) -> list:
    """Feed ``mon`` the NIS of the sensor rows of the keyframe ``fac`` just made (``graph``,
    ``new_values``; :attr:`Factors.rows`) against ``isam``'s prediction, each accepted when
    within its stream's gate (as a filter's gate would); ``read`` as :func:`predicted_nis`.
    Returns the verdicts ``(position in graph, measurement, accepted)`` of the rows tested."""
    rows, streams = {}, {}
    for pos, meas, f in fac.rows:
        twin = f if meas.stream not in fac.p.robust else fac.with_loss(meas, f, ("none", 0.0))
        if twin.dim() == mon.dims.get(meas.stream):
            rows[pos], streams[pos] = twin, meas
    if not rows:
        return []
    verdicts = []
    for pos, (nis, white) in predicted_nis(isam, graph, new_values, rows, fac.dims, read).items():
        if not math.isfinite(nis):
            continue
        meas = streams[pos]
        t = float(fac.p.kt[meas.keyframe])
        ok = bool(nis <= mon.gates[meas.stream])
        mon.observe(meas.stream, t, ok, nis, white)
        verdicts.append((pos, meas, ok))
    return verdicts


def gated_out(verdicts, runs: dict, reject_run: int) -> set[int]:
    """The rows of one keyframe that the filters' gate leaves out, for an incremental graph.

    A row of a stream in ``runs`` (stream -> its current run of consecutive rejections,
    updated here) that :func:`observe` found beyond its gate is left out, as a filter leaves
    out the update, until ``reject_run`` of them in a row say that the prediction, not the
    sensor, is off: from that one on the stream's rows go in until one is within the gate
    again, as a filter re-opens (``status.monitors.recover``), so that the readings that
    disagree with a prediction that drifted away pull it back. Returns their positions."""
    out = set()
    k = max(int(reject_run), 1)
    for pos, meas, ok in verdicts:
        if meas.stream not in runs:
            continue
        runs[meas.stream] = 0 if ok else runs[meas.stream] + 1
        if not ok and runs[meas.stream] < k:
            out.add(pos)
    return out


def without(graph, positions: set, new_values):
    """``graph`` without the factors at ``positions``, except one that alone holds a variable
    of ``new_values`` (the update would leave it undetermined). Returns the graph and the
    positions left out."""
    import gtsam

    keep = [j for j in range(graph.size()) if j not in positions]
    held = {k for j in keep for k in graph.at(j).keys()}
    new = set(new_values.keys())
    left = set()
    for j in sorted(positions):
        if all(k in held or k not in new for k in graph.at(j).keys()):
            left.add(j)
        else:
            keep.append(j)
            held.update(graph.at(j).keys())
    if not left:
        return graph, left
    out = gtsam.NonlinearFactorGraph()
    for j in sorted(keep):
        out.push_back(graph.at(j))
    return out, left


def summary(mon) -> dict:
    """``extra["nis"]``: per tested stream, its readings, those beyond its gate and the mean
    NIS of the others (expected: the stream's dimension)."""
    out = {}
    for s, st in mon.live.items():
        if st.n:
            mean = st.tsum / st.tn if st.tn else None
            out[s] = {"readings": st.n, "beyond_gate": st.n - st.tn, "mean_nis": mean}
    return out


def findings(mon, problem) -> list:
    """The findings of ``mon``'s streaming checks over ``problem``'s keyframe span, without
    their outage check (the graph has its own); the scans evaluate their last windows first
    (:meth:`~odofuse.status.monitors.FilterMonitor.end`)."""
    mon.end()
    return mon.stream_findings((float(problem.kt[0]), float(problem.kt[-1])), outage=False)
