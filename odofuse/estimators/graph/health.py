"""The graph's self-checks without ground truth: residuals, calibration, jumps, solver.

Owns the per-factor residuals of a solution (:func:`factor_residuals`: whitened chi-square
of every sensor, gyro and odometry factor with the *Gaussian* part of its noise model, so a
robust loss does not hide a residual), the per-stream summary and outlier counts
(:func:`residual_summary`), the variance components of a solution and the error covariance
they imply (:func:`variance_components`, the batch smoother's self-scaling used by
:mod:`odofuse.cross_check`), and the :class:`~odofuse.health.Finding` records of a graph run
(:func:`graph_findings`, :func:`solver_findings`, :func:`marginals_finding`).

Every threshold is fixed a priori from the chi-square distribution, never from a ground
truth:

* residual scale: the median whitened chi-square of a stream's factors over the median of
  the chi-square distribution of their dimension above :data:`SCALE_RATIO` (4: the residuals
  are more than twice the sigma the config claims; the median is blind to a robust loss's
  outliers);
* outliers: more than :data:`OUTLIER_FRACTION` of a stream's factors beyond its 0.999
  chi-square bound (100 times the 0.1 % expected of a right noise model);
* calibration: a calibration variable more than :data:`CALIBRATION_SIGMAS` prior sigmas from
  its prior (probability 6e-7 under the prior the config gave);
* keyframe jumps: an odometry factor beyond the ``1 - 1e-6`` chi-square bound over which
  the estimate moved more than :data:`JUMP_M` farther than the odometry says (an estimate
  that stays put where the odometry reports a spurious step is the robust loss working,
  not a jump);
* residual windows (:func:`window_findings`): the summed whitened chi-square of
  :data:`WINDOW` consecutive odometry (or gyro) factors above the chi-square quantile of
  their summed dimension at ``1 - WINDOW_ALPHA / (n // WINDOW)`` (Bonferroni over the run's
  windows), the filters' NIS-window test with their default window and false-alarm
  probability. At a least-squares optimum the residuals' covariance is the noise model's
  minus what the estimate absorbed, so a window's sum is at most chi-square distributed
  with that dimension when the noise model is right: the test can only be conservative.

Also owns the slip note of a graph run (:func:`slip_findings`; the widening itself is
:func:`odofuse.estimators.graph.factors.slip_scales`).
"""

from __future__ import annotations

import math

import numpy as np

from odofuse import se2
from odofuse.estimators.graph.factors import slip_scales
from odofuse.estimators.graph.keys import X
from odofuse.health import Finding

SCALE_RATIO = 4.0
OUTLIER_FRACTION = 0.10
OUTLIER_PROBABILITY = 0.999
CALIBRATION_SIGMAS = 5.0
JUMP_M = 1.0
JUMP_PROBABILITY = 1.0 - 1e-6
#: Consecutive factors of a residual window and the false-alarm probability of the windows
#: over the run: the filters' ``nis_window`` and ``nis_alpha`` defaults.
WINDOW = 20
WINDOW_ALPHA = 1e-3
#: Redundancy (degrees of freedom) below which a variance group's factor is not estimated:
#: its relative standard deviation ``sqrt(2 / r)`` would exceed 0.32.
MIN_REDUNDANCY = 20.0
#: State dimensions above which only the global variance factor is estimated (the per-stream
#: estimation's sparse solves grow with rows times states).
MAX_VCE_DIMS = 6000
#: The variance group of priors and pseudo-observations (never re-scaled).
PRIOR_GROUP = "prior"


def _chi2(f, values) -> tuple[float, int, np.ndarray]:
    """Whitened chi-square of a noise-model factor with its Gaussian (non-robust) part."""
    e = np.atleast_1d(np.asarray(f.unwhitenedError(values), dtype=float))
    nm = f.noiseModel()
    base = nm.noise() if hasattr(nm, "robust") else nm
    sig = np.asarray(base.sigmas(), dtype=float)
    dof = int(np.count_nonzero(np.isfinite(sig)))
    return float(base.squaredMahalanobisDistance(e)), dof, e


def robust_weights(factors, values, floor: float = 1e-6) -> np.ndarray:
    """The IRLS weight ``rho'(r) / r`` of each robust factor at ``values`` (1 if not robust).

    ``r`` is the whitened residual norm with the Gaussian part of the noise model; weights
    are floored at ``floor`` so that a frozen weight keeps the factor's covariance finite.
    """
    out = np.ones(len(factors))
    for j, f in enumerate(factors):
        nm = f.noiseModel()
        if hasattr(nm, "robust"):
            chi2, _, _ = _chi2(f, values)
            out[j] = max(float(nm.robust().weight(math.sqrt(chi2))), floor)
    return out


def factor_groups(fac, graph) -> list[str]:
    """The variance group of each factor of ``graph``: its stream (a sensor, a gyro, the
    odometry) or ``"prior"`` (priors, bias-walk steps, landmark pins: pseudo-observations
    whose scale the config sets, not a sensor's)."""
    label = {id(f): meas.stream for meas, f in fac.created}
    label.update({id(f): stream for stream, _n, f in fac.gyro_created})
    label.update({id(f): fac.p.odometry_stream for _i, f in fac.odometry_created})
    return [label.get(id(graph.at(j)), PRIOR_GROUP) for j in range(graph.size())]


def _whitened_system(graph, values):
    """Whitened Jacobian ``A`` (m, n; sparse CSR), residual ``b`` (m,) and each row's factor
    index, of ``graph`` linearised at ``values`` (a robust factor with its IRLS weight, as
    the solver and the marginals see it), and the column offset and dimension of each key."""
    from scipy import sparse

    lin = graph.linearize(values)
    zero = values.zeroVectors()
    cols, n = {}, 0
    for key in values.keys():
        d = int(np.asarray(zero.at(key)).size)
        cols[int(key)] = (n, d)
        n += d
    ri, ci, vals, bs, owner, m = [], [], [], [], [], 0
    for j in range(lin.size()):
        f = lin.at(j)
        if f is None:
            continue
        a, b = f.jacobian()
        a, b = np.atleast_2d(np.asarray(a, dtype=float)), np.atleast_1d(np.asarray(b, float))
        at = 0
        for key in f.keys():
            off, d = cols[int(key)]
            blk = a[:, at : at + d]
            r, c = np.nonzero(blk)
            ri.append(r + m)
            ci.append(c + off)
            vals.append(blk[r, c])
            at += d
        bs.append(b)
        owner.append(np.full(b.size, j))
        m += b.size
    cat = np.concatenate
    A = sparse.csr_matrix((cat(vals), (cat(ri), cat(ci))), shape=(m, n))
    return A, cat(bs), cat(owner), cols


def _factor(N):
    """Sparse LU of the symmetric positive-definite ``N`` with a symmetric fill-reducing
    ordering and diagonal pivots (a Cholesky in effect: no pivoting that destroys sparsity)."""
    from scipy.sparse.linalg import splu

    return splu(
        N, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )


def _hat_traces(A, N, rows, scale, lu, chunk) -> dict:
    """Per group ``tr(N^-1 A_g^T A_g / c_g)`` (the hat matrix's diagonal summed over the
    group's rows; the largest group by difference: the traces sum to ``n``)."""
    largest = max(rows, key=lambda g: rows[g].size)
    out = {}
    for g, idx in rows.items():
        if g == largest:
            continue
        t = 0.0
        for k in range(0, idx.size, chunk):
            a = A[idx[k : k + chunk]]
            t += float(np.sum(a.toarray().T * lu.solve(a.T.toarray()))) / scale[g]
        out[g] = t
    out[largest] = A.shape[1] - sum(out.values())
    return out


def variance_components(
    graph, values, groups, position_keys, chunk: int = 256, iterations: int = 20
) -> dict:
    """Variance components of a least-squares solution and the error covariance they imply.

    Förstner's iterated variance component estimation on the system linearised at the
    optimum: the noise of group ``g`` (:func:`factor_groups`) is ``c_g`` times what its
    model says; with weights ``1 / c_g`` (start: 1), the weighted solution's whitened
    residuals ``v_g`` (a robust factor with its IRLS weight, as it enters the normal
    equations) and the group's redundancy ``r_g = m_g - tr(N^-1 N_g) / c_g`` (``N = sum_g
    N_g / c_g``, ``N_g = A_g^T A_g`` the group's whitened normal matrix, ``m_g`` its residual
    dimensions, ``sum_g r_g = m - n``) give ``c_g <- v_g^T v_g / r_g``, until no ``c_g``
    moves by more than 0.1 % (at most ``iterations`` passes; a single pass is biased when the
    groups' relative weights are off). A group whose redundancy is below
    :data:`MIN_REDUNDANCY` keeps ``c_g = 1`` (too few degrees of freedom: relative standard
    deviation ``sqrt(2 / r_g)`` above 0.32), and so does the ``prior`` group. The solution
    itself (computed with the model's weights) is not changed; its error covariance under
    those components is the sandwich ``N_0^-1 (sum_g c_g N_g) N_0^-1`` (``N_0 = sum_g N_g``,
    whose inverse is the marginals' covariance). Förstner, "Ein Verfahren zur Schätzung von
    Varianz- und Kovarianzkomponenten", AVN 86 (1979); Koch, *Parameter Estimation and
    Hypothesis Testing in Linear Models* (1999), section 3.6.

    Each pass costs one sparse solve per residual row outside the largest group; above
    :data:`MAX_VCE_DIMS` state dimensions (Plaza1's 16,400: 610 s on the loaded 2 shared
    cores, against 78 s for the smoother itself) only the global factor ``sigma0^2`` is
    estimated (``method: global``, one group: the covariance scales by ``sigma0^2``, no solve).

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph
    values : gtsam.Values
        The optimum.
    groups : list of str
        Group of each factor of ``graph``.
    position_keys : list of int
        Pose2 keys whose position covariance is scaled.
    chunk : int
        Right-hand sides per sparse solve (memory ``n * chunk`` floats).
    iterations : int
        Most passes of the estimation.

    Returns
    -------
    dict
        ``method`` (``per-stream`` or ``global``), ``variance_factor`` (global
        ``sum v^T v / (m - n)`` at the optimum, None when ``m <= n``), ``redundancy``
        (``m - n``), ``iterations``, ``groups``: group ->
        ``{"variance_factor" (c_g), "redundancy" (r_g), "dims" (m_g), "estimated"}`` (per
        stream only), and
        ``position_variance_scale``: mean trace of the sandwich's position blocks over the
        mean trace of ``N_0^-1``'s (1 when no group was estimated).
    """
    from scipy import sparse

    A, b, owner, cols = _whitened_system(graph, values)
    m, n = A.shape
    redundancy = m - n
    sigma0 = float(b @ b / redundancy) if redundancy > 0 else None
    if n > MAX_VCE_DIMS:  # the global factor: no solve (the covariance scales as one)
        return {
            "method": "global",
            "variance_factor": sigma0,
            "redundancy": int(redundancy),
            "position_variance_scale": sigma0 if sigma0 is not None and sigma0 > 0 else 1.0,
        }
    label = np.array(groups, dtype=object)[owner]
    rows = {g: np.flatnonzero(label == g) for g in sorted(set(label))}
    scale = dict.fromkeys(rows, 1.0)
    free = {g for g in rows if g != PRIOR_GROUP}
    passes, red = 0, {}
    while passes < iterations:
        passes += 1
        weight = np.empty(m)
        for g, idx in rows.items():
            weight[idx] = 1.0 / scale[g]
        w = sparse.diags(weight)
        N = (A.T @ w @ A).tocsc()
        lu = _factor(N)
        dx = lu.solve(A.T @ (w @ b))
        v = b - A @ dx
        trace = _hat_traces(A, N, rows, scale, lu, chunk)
        red = {g: rows[g].size - trace[g] for g in rows}
        new = dict(scale)
        for g in list(free):
            if red[g] < MIN_REDUNDANCY:
                free.discard(g)
                new[g] = 1.0
            else:
                new[g] = float(v[rows[g]] @ v[rows[g]] / red[g])
        moved = max((abs(new[g] / scale[g] - 1.0) for g in rows), default=0.0)
        scale = new
        if moved < 1e-3:
            break
    out_groups = {
        g: {
            "variance_factor": float(scale[g]),
            "redundancy": float(red[g]),
            "dims": int(rows[g].size),
            "estimated": g in free,
        }
        for g in rows
    }
    N0 = (A.T @ A).tocsc()
    lu0 = _factor(N0)
    pos = np.concatenate([np.arange(cols[int(k)][0], cols[int(k)][0] + 2) for k in position_keys])
    model = sandwich = 0.0
    for k in range(0, pos.size, chunk):
        sel = pos[k : k + chunk]
        e = np.zeros((n, sel.size))
        e[sel, np.arange(sel.size)] = 1.0
        y = lu0.solve(e)
        model += float(np.sum(y[sel, np.arange(sel.size)]))
        ay = A @ y
        sandwich += sum(scale[g] * float(np.sum(ay[rows[g]] ** 2)) for g in rows)
    return {
        "method": "per-stream",
        "variance_factor": sigma0,
        "redundancy": int(redundancy),
        "iterations": passes,
        "groups": out_groups,
        "position_variance_scale": sandwich / model if model > 0 else 1.0,
    }


def gyro_error(problem, values, stream: str, n: int) -> float:
    """rad, ``wrap(theta_j - theta_i + b T - dtheta)`` of the ``n``-th gyro increment."""
    inc = problem.gyro[stream]
    i = int(inc.interval[n])
    b = 0.0
    name = problem.state_name(stream, "gyro_bias")  # a second gyro's own bias
    if name in problem.calib and values.exists(problem.bias_key(name, i)):
        m = problem.models[stream]
        if "gyro_bias" in getattr(m, "calib_states", ()):
            b = float(values.atVector(problem.bias_key(name, i))[0])
    th0, th1 = values.atPose2(X(i)).theta(), values.atPose2(X(i + 1)).theta()
    return float(se2.wrap(th1 - th0 + b * float(inc.T[n]) - float(inc.dtheta[n])))


def factor_residuals(problem, fac, values) -> dict[str, dict]:
    """Per stream: time (s), whitened chi-square and dimension of each of its factors.

    Returns
    -------
    dict
        stream -> ``{"t": (F,), "chi2": (F,), "dof": (F,) int}``; the odometry stream also
        has ``"jump"`` (F,): how much farther (m) the estimate moved over each odometry
        interval than the odometry says (negative when it moved less, e.g. when it rejected
        a spurious odometry step).
    """
    rows: dict[str, list] = {}
    kt = problem.kt
    for meas, f in fac.created:
        chi2, dof, _ = _chi2(f, values)
        rows.setdefault(meas.stream, []).append((kt[meas.keyframe], chi2, dof, 0.0))
    for stream, n, _f in fac.gyro_created:
        e = gyro_error(problem, values, stream, n)
        i = int(problem.gyro[stream].interval[n])
        rows.setdefault(stream, []).append((kt[i + 1], e * e / problem.gyro[stream].var[n], 1, 0.0))
    for i, f in fac.odometry_created:
        chi2, dof, _ = _chi2(f, values)
        a, b = values.atPose2(X(i - 1)), values.atPose2(X(i))
        moved = math.hypot(b.x() - a.x(), b.y() - a.y())
        jump = moved - math.hypot(*problem.deltas[i - 1, :2])  # beyond what odometry says
        rows.setdefault(problem.odometry_stream, []).append((kt[i], chi2, dof, jump))
    out = {}
    for stream, r in rows.items():
        a = np.array(r, dtype=float).reshape(-1, 4)
        out[stream] = {"t": a[:, 0], "chi2": a[:, 1], "dof": a[:, 2].astype(int), "jump": a[:, 3]}
    return out


def _chi2_ppf(p: float, dof) -> np.ndarray:
    from scipy.stats import chi2

    return chi2.ppf(p, np.maximum(np.asarray(dof), 1))


def residual_summary(problem, residuals: dict) -> dict:
    """Per stream: factors, mean chi-square per dimension, median ratio, beyond-0.999 fraction
    and the count beyond the model's own gate (``outliers``, the sensors' ``gate``)."""
    from odofuse.measurements import gate_threshold

    out = {}
    for stream, r in residuals.items():
        chi2, dof = r["chi2"], r["dof"]
        if chi2.size == 0:
            continue
        ratio = float(np.median(chi2) / np.median(_chi2_ppf(0.5, dof)))
        beyond = float(np.mean(chi2 > _chi2_ppf(OUTLIER_PROBABILITY, dof)))
        s = {
            "factors": int(chi2.size),
            "chi2_per_dof": float(chi2.sum() / max(int(dof.sum()), 1)),
            "median_ratio": ratio,
            "beyond_999": beyond,
        }
        m = problem.models.get(stream)
        if m is not None and getattr(m, "gate", None) is not None:
            thr = np.array([gate_threshold(m.gate, int(d)) for d in dof])
            s["outliers"] = int(np.count_nonzero(chi2 > thr))
        out[stream] = s
    return out


def graph_findings(
    problem, values, residuals: dict, summary: dict, stitched=False, optimum=True
) -> list:
    """Findings on residual scale, outlier fraction, residual windows, calibration values,
    keyframe jumps, and the slip note.

    ``stitched``: the poses were taken from different solutions (the fixed-lag smoother's,
    each as it left the window), so the residual scale and outlier checks of the factors
    *between* poses (odometry, gyro) do not apply; the jump check does. ``optimum``: the
    values are a converged batch least-squares solution (the smoother), the premise of
    :func:`window_findings`.
    """
    out: list[Finding] = []
    relative = {problem.odometry_stream, *problem.gyro}
    for stream, s in sorted(summary.items()):
        if stitched and stream in relative:
            continue
        t = residuals[stream]["t"]
        span = (float(t.min()), float(t.max()))
        if s["median_ratio"] > SCALE_RATIO:
            out.append(
                Finding(
                    "residuals",
                    f"median whitened residual {math.sqrt(s['median_ratio']):.1f}x the "
                    "sigma of its noise model (median chi-square "
                    f"{s['median_ratio']:.1f}x the expected): the noise model is too "
                    "optimistic or the estimate is wrong",
                    sensor=stream,
                    t_start=span[0],
                    t_end=span[1],
                    figure=s["median_ratio"],
                )
            )
        if s["beyond_999"] > OUTLIER_FRACTION:
            out.append(
                Finding(
                    "outliers",
                    f"{100 * s['beyond_999']:.0f} % of {s['factors']} factors beyond their "
                    "0.999 chi-square bound (0.1 % expected)",
                    sensor=stream,
                    t_start=span[0],
                    t_end=span[1],
                    figure=s["beyond_999"],
                )
            )
    out += window_findings(problem, residuals, optimum and not stitched)
    out += outage_findings(problem)
    out += slip_findings(problem, slip_scales(problem))
    out += calibration_findings(problem, values) + gauge_findings(problem)
    odo = residuals.get(problem.odometry_stream)
    if odo is not None and odo["chi2"].size:
        bad = (odo["chi2"] > _chi2_ppf(JUMP_PROBABILITY, odo["dof"])) & (odo["jump"] > JUMP_M)
        if bad.any():
            idx = np.flatnonzero(bad)
            out.append(
                Finding(
                    "jumps",
                    f"{idx.size} keyframe intervals where the estimate moves more than "
                    f"{JUMP_M:g} m farther than the odometry says (largest "
                    f"{odo['jump'][idx].max():.1f} m)",
                    sensor=problem.odometry_stream,
                    t_start=float(odo["t"][idx[0]]),
                    t_end=float(odo["t"][idx[-1]]),
                    figure=float(odo["jump"][idx].max()),
                )
            )
    return out


def window_findings(problem, residuals: dict, optimum: bool = True) -> list[Finding]:
    """Windows of odometry and gyro factors whose residuals exceed their chi-square bound.

    For each relative stream (the odometry and the gyro increments) without a robust loss
    (a robust loss declares outliers expected: its factors are judged by the outlier
    fraction), the sum of the whitened chi-square of every :data:`WINDOW` consecutive
    factors is compared with the ``1 - WINDOW_ALPHA / (n // WINDOW)`` quantile of the
    chi-square law of their summed dimension. One finding per stream: the span from the
    first to the last flagged window, how many windows and seconds, and the worst window's
    chi-square per dimension.

    Only for a batch optimum (``optimum``: the smoother): the bound holds for the residuals
    of a least-squares minimum. The fixed-lag smoother's poses come from different windows,
    and an iSAM2 estimate is the optimum only up to its relinearisation thresholds: on
    Plaza1 (``configs/plaza1-isam2.yaml``, position NEES 1.43) its odometry residuals reach
    a window chi-square of 136 per dimension between 3859 and 5724 s, where the batch
    optimum of the same odometry factors (the smoother without odometry calibration) has
    0.005 per dimension.
    """
    from odofuse import chi2

    if not optimum:
        return []
    out = []
    for stream in (problem.odometry_stream, *problem.gyro):
        r = residuals.get(stream)
        loss = problem.robust.get(stream, ("none", 0.0))[0]
        if r is None or r["chi2"].size < WINDOW or loss != "none":
            continue
        w, t = WINDOW, r["t"]
        c = np.concatenate([[0.0], np.cumsum(np.minimum(r["chi2"], 1e12))])
        k = np.concatenate([[0], np.cumsum(r["dof"])])
        total, dof = c[w:] - c[:-w], k[w:] - k[:-w]  # window j: factors j .. j+w-1
        alpha = WINDOW_ALPHA / max(r["chi2"].size // w, 1)
        flags = total > chi2.ppf(1.0 - alpha, np.maximum(dof, 1))
        if not flags.any():
            continue
        idx = np.flatnonzero(flags)
        inside = np.zeros(t.size, dtype=bool)
        for j in idx:
            inside[j : j + w] = True
        covered = float(np.sum(np.diff(t)[inside[1:] & inside[:-1]]))
        worst = float(np.max(total[idx] / dof[idx]))
        out.append(
            Finding(
                "residual_windows",
                f"{idx.size} window(s) of {w} factors with residuals above their chi-square "
                f"bound (false alarm {WINDOW_ALPHA:g} over the run), {covered:.1f} s in all; "
                f"worst chi-square per dimension {worst:.3g} (expected at most 1): the noise "
                "model is too optimistic there (wheel slip, a stuck encoder, a gyro fault)",
                sensor=stream,
                t_start=float(t[idx[0]]),
                t_end=float(t[min(idx[-1] + w - 1, t.size - 1)]),
                figure=worst,
            )
        )
    return out


def outage_findings(problem) -> list[Finding]:
    """A sensor silent for more than half of the run: the filters' ``outage`` check.

    The rule and its bound are the filters' (:func:`odofuse.estimators.monitors.outage_findings`,
    issue 10 item 5: no score over less than half of the span without a warning; more than
    the default ``reject_run`` of the stream's readings), given the times of the rows that got a
    factor (a gyro: the ends of its keyframe intervals). Over such a gap the graph's poses
    rest on odometry alone, a drift no residual can show.
    """
    from odofuse.declarations import FilterOptions
    from odofuse.estimators.monitors import outage_findings as stream_outage

    times: dict[str, list] = {}
    for meas in problem.measurements:
        times.setdefault(meas.stream, []).append(float(problem.kt[meas.keyframe]))
    for stream, inc in problem.gyro.items():
        times[stream] = list(problem.kt[np.asarray(inc.interval, dtype=int) + 1])
    if len(problem.kt) < 2 or not times:
        return []
    t0, t1, run = float(problem.kt[0]), float(problem.kt[-1]), FilterOptions().reject_run
    out = []
    for stream, ts in sorted(times.items()):
        out += stream_outage(stream, ts, t0, t1, run)
    return out


def slip_findings(problem, scales) -> list[Finding]:
    """The (non-degrading) note of the keyframe intervals whose odometry noise was widened."""
    n = int(np.count_nonzero(scales > 1.0))
    if not n:
        return []
    j = np.flatnonzero(scales > 1.0)
    stream = next(s for s in problem.models if s in problem.gyro)
    return [
        Finding(
            "slip",
            f"gyro and wheels disagreed on {n} keyframe interval(s): the odometry noise of "
            f"those intervals was widened to cover it (robust odometry, up to "
            f"x{float(scales.max()):.3g})",
            sensor=stream,
            t_start=float(problem.kt[j[0]]),
            t_end=float(problem.kt[j[-1] + 1]),
            figure=float(n),
            degrades=False,
        )
    ]


def gauge_findings(problem) -> list[Finding]:
    """A finding when the configuration leaves the map's scale to the priors alone.

    With unknown landmarks (``slam``), an estimated range scale and an estimated odometry
    distance scale (``ds_scale``), scaling the map, the trajectory and ``ds_scale`` by
    ``lambda`` and the range scale by ``1 / lambda`` leaves every range and odometry factor
    unchanged: only the two priors hold the scale.
    """
    oc = problem.odometry_calibration
    if not (problem.options.slam and "range_scale" in problem.calib and oc is not None):
        return []
    if "ds_scale" not in oc.names:
        return []
    return [
        Finding(
            "calibration",
            "range SLAM estimating both range_scale and ds_scale: the map's scale is fixed by "
            "their priors only (estimate one of them, or give the map)",
        )
    ]


def calibration_findings(problem, values) -> list[Finding]:
    """A finding per calibration variable more than :data:`CALIBRATION_SIGMAS` from its prior.

    A walking bias is judged by its final value against its prior grown by the walk
    (:meth:`~odofuse.estimators.graph.problem.GraphProblem.prior_sigma_at` the last keyframe).
    """
    states = [
        (
            name,
            problem.final_key(name),
            0,
            value,
            float(problem.prior_sigma_at(name, problem.kt[-1])),
        )
        for name, (_, value, _) in problem.calib.items()
    ]
    oc = problem.odometry_calibration
    if oc is not None:
        states += [
            (name, problem.odometry_key, j, oc.nominal[j], oc.sigma[j])
            for j, name in enumerate(oc.names)
        ]
    out = []
    for name, key, j, prior, sigma in states:
        if not values.exists(key) or not sigma > 0:
            continue
        v = float(values.atVector(key)[j])
        z = abs(v - prior) / sigma
        if z > CALIBRATION_SIGMAS:
            out.append(
                Finding(
                    "calibration",
                    f"{name} = {v:.4g} is {z:.1f} prior sigmas from its prior {prior:g} "
                    f"(sigma {sigma:g}): implausible under that prior (the prior is too tight or "
                    "the calibration absorbed another error)",
                    figure=z,
                )
            )
    return out


def solver_findings(solver: str, reason: str, iterations: int, detail: str = "") -> list[Finding]:
    """Findings for a solver that stopped without converging (``reason`` not ``converged``)."""
    if reason == "converged":
        return []
    text = {
        "max_iterations": f"stopped at its iteration cap ({iterations} iterations) "
        "without converging",
        "no_decrease": f"found no step that lowers the error after {iterations} iterations "
        "(the linear systems were indeterminate)",
        "non_finite": "has a non-finite error at the initial values (not solved)",
    }.get(reason, reason)
    msg = f"{solver} {text}" + (f": {detail}" if detail else "")
    return [Finding("solver", msg, figure=float(iterations))]


def marginals_finding(detail: str, regularised: bool) -> Finding:
    """The finding of a marginal-covariance computation that failed."""
    what = (
        "regularised with a weak prior on every variable; the covariance of the directions "
        "the data do not determine is that prior's"
        if regularised
        else "covariances omitted"
    )
    return Finding("covariance", f"marginal covariances: indeterminate system ({detail}); {what}")
