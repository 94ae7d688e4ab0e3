"""The graph's self-checks without ground truth: residuals, calibration, jumps, solver.

Owns the per-factor residuals of a solution (:func:`factor_residuals`: whitened chi-square
of every sensor, gyro and odometry factor with the *Gaussian* part of its noise model, so a
robust loss does not hide a residual), the per-stream summary and outlier counts
(:func:`residual_summary`), and the :class:`~odofuse.status.findings.Finding` records of a graph run
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
* rejection count (:func:`rejection_count_findings`): the filters' count of readings beyond
  their gate among ``nis_window`` consecutive ones, on each gated sensor stream's residuals
  at the optimum, against the binomial bound of the filters' null (the gate's own probability
  plus a real sensor's few gross readings, ``gross_fraction``; ``nis_alpha`` over the run).

Also owns the slip note of a graph run (:func:`slip_findings`; the widening itself is
:func:`odofuse.estimators.graph.factors.slip_scales`).
"""

from __future__ import annotations

import math

import numpy as np

from odofuse import se2
from odofuse.status.findings import Finding

# odofuse.estimators.graph (keys, factors) is imported inside the functions that use it: the
# graph package imports this module while it initialises.

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


def gyro_error(problem, values, stream: str, n: int) -> float:
    """rad, ``wrap(theta_j - theta_i + b T - dtheta)`` of the ``n``-th gyro increment."""
    from odofuse.estimators.graph.keys import X

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
    from odofuse.estimators.graph.keys import X

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
    # odofuse.chi2: scipy.stats' numbers without its import (8 s of a first isam2 run on w100)
    from odofuse import chi2

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
            levels = np.unique(dof)  # one quantile per dimension, not per factor
            thr = np.array([gate_threshold(m.gate, int(d)) for d in levels])
            thr = thr[np.searchsorted(levels, dof)]
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
    from odofuse.estimators.graph.factors import slip_scales

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
    out += rejection_count_findings(problem, residuals, optimum and not stitched)
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


def rejection_count_findings(problem, residuals: dict, optimum: bool = True) -> list[Finding]:
    """The filters' rejection count on the batch smoother's residuals at its optimum.

    For each sensor stream with a gate (not a gyro: its factors lie between poses, as in
    :mod:`odofuse.estimators.graph.innovations`), its factors in time order are scanned as a
    filter's readings are (:func:`odofuse.status.streaming.count_bound`, at the incremental
    graphs' :data:`~odofuse.estimators.graph.innovations.NIS_OPTIONS`): every
    ``nis_window / 4`` factors and at the last one, those among the last ``nis_window`` whose
    whitened chi-square (Gaussian part of the noise model: a robust loss does not hide them)
    is beyond the gate,
    against the binomial bound of the filters' null
    (:func:`odofuse.status.streaming.count_probability`: the gate's own probability
    ``1 - gate`` plus the ``gross_fraction`` of gross readings a real sensor has, 3 %),
    ``nis_alpha`` spent over the evaluations. At a least-squares optimum a residual's
    covariance is the noise model's minus what the estimate absorbed, so on a matching log
    each factor is beyond its gate with probability at most that of a filter's innovation.
    A burst of gross readings that the graph's gate loss sets aside (GPS multipath at 4
    sigmas) leaves its residuals beyond the gate, where the estimate can hold (the loss is
    working) and the outlier fraction of the whole stream stays under
    :data:`OUTLIER_FRACTION`; a real GNSS receiver's two or three gross fixes in a window do
    not reach the bound (docs/trust.md, "A real sensor's gross readings"). Only for a batch
    optimum (``optimum``: the smoother); iSAM2 and fixed-lag count their predicted
    innovations (:mod:`odofuse.estimators.graph.innovations`).
    """
    from odofuse.estimators.graph.innovations import NIS_OPTIONS
    from odofuse.measurements import gate_threshold
    from odofuse.status.streaming import count_bound, count_probability, mean_stride

    if not optimum:
        return []
    w, alpha = int(NIS_OPTIONS.nis_window), float(NIS_OPTIONS.nis_alpha)
    stride = mean_stride(w)
    out = []
    for stream, m in sorted(problem.models.items()):
        r = residuals.get(stream)
        if stream in problem.gyro or r is None or r["chi2"].size < w:
            continue
        gate = gate_threshold(getattr(m, "gate", None), int(m.dim))
        p = count_probability(gate, int(m.dim), float(NIS_OPTIONS.gross_fraction))
        if p <= 0.0:
            continue
        order = np.argsort(r["t"], kind="stable")
        t = r["t"][order]
        beyond = np.concatenate([[0], np.cumsum(r["chi2"][order] > gate)])
        hits, worst, bound, span = 0, 0, 0, None
        ends = list(range(w, t.size + 1, stride))
        if ends[-1] != t.size:  # the last window too, as the filters' count ends a run
            ends.append(t.size)
        for j, end in enumerate(ends, start=1):
            k, _ = count_bound(j, w, p, alpha)
            count = int(beyond[end] - beyond[end - w])
            if count >= k:
                hits += 1
                if count > worst:
                    worst, bound = count, k
                first = span[0] if span else float(t[end - w])
                span = (first, float(t[end - 1]))
        if hits:
            out.append(
                Finding(
                    "rejection_count",
                    f"{worst} of {w} consecutive readings beyond the gate at the optimum (a "
                    f"matching log with a real sensor's few gross readings puts {p:.3g} of "
                    f"them there; {bound} or more at <= {alpha:g} over the run), {hits} "
                    "window(s): the estimate and this sensor disagree (gross readings that "
                    "the robust loss set aside, or a noise model more optimistic than the "
                    "readings)",
                    sensor=stream,
                    t_start=span[0],
                    t_end=span[1],
                    figure=float(worst),
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

    The rule and its bound are the filters' (:func:`odofuse.status.streaming.outage_findings`,
    issue 10 item 5: no score over less than half of the span without a warning; more than
    the default ``reject_run`` of the stream's readings), given the times of the rows that got a
    factor (a gyro: the ends of its keyframe intervals). Over such a gap the graph's poses
    rest on odometry alone, a drift no residual can show.
    """
    from odofuse.declarations import FilterOptions
    from odofuse.status.streaming import outage_findings as stream_outage

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
    """The (non-degrading) note of the keyframe intervals whose odometry noise was widened,
    and the filters' ``slip_run`` (:func:`odofuse.status.slip.slip_run_findings`): two or
    more consecutive slipping intervals spanning more than it (a wheel spinning free, dragged
    or with its encoder stuck; 1e-6 on a matching log)."""
    from odofuse.status.slip import slip_run_findings

    n = int(np.count_nonzero(scales > 1.0))
    if not n:
        return []
    j = np.flatnonzero(scales > 1.0)
    stream = next(s for s in problem.models if s in problem.gyro)
    runs = np.split(j, np.flatnonzero(np.diff(j) > 1) + 1)
    spans = [(float(problem.kt[r[0]]), float(problem.kt[r[-1] + 1])) for r in runs if r.size > 1]
    longest = max(spans, key=lambda ab: ab[1] - ab[0], default=(0.0, 0.0))
    out = slip_run_findings(stream, *longest, "keyframe interval")
    return out + [
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
