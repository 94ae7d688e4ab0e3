"""Checks of a pose track without ground truth: covariance health, particle-cloud collapse,
dead reckoning's gyro-vs-wheels tell-tale, and a calibration state still being learnt over
most of the run (``learning``).

:mod:`odofuse.status.monitors` owns the per-reading monitor of the filters (NIS windows,
rejection runs, recovery) and calls these on the filter's track; dead reckoning calls
:func:`gyro_wheel_findings` directly. Thresholds are chosen a priori from statistics, never
from ground truth.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from odofuse.declarations import FilterOptions
from odofuse.status.findings import Finding
from odofuse.trajectory import pose_blocks


def _spans(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[(i0, i1), ...]`` index ranges (inclusive) of the runs of True in ``flags``."""
    if not flags.any():
        return []
    d = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1, strict=True))


def _s(x: float) -> str:
    return f"{x:.3g}"


def _correlation_condition(
    P, block: int | None = None, cap: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Which covariances of ``P`` (N, n, n) are finite with a positive diagonal (N,) bool, and
    the condition numbers (M,) of their correlation matrices; in blocks
    (:func:`odofuse.trajectory.pose_blocks`), so the temporaries stay a few MB on any run
    (whole-run copies were 4 x 130 MB on a 10 h log at 50 Hz).

    ``cap`` > 0 (poses, n = 3): a matrix whose condition number is certainly at most ``cap``
    gets that certainty's bound instead (``<= cap``), without an eigen-decomposition: a
    correlation matrix has trace 3, so ``l_max <= 3`` and, by AM-GM on the other two
    eigenvalues, ``l_min >= det / (3/2)^2``; the bound is ``6.75 / det C``
    (:func:`_correlation_det3`; the live health's pass over its kept poses: 5x faster).
    """
    finite = np.empty(len(P), dtype=bool)
    out = []
    n = P.shape[-1]
    for b in pose_blocks(len(P), block):
        Pb = P[b]
        q = Pb.reshape(len(Pb), n * n)
        diag = q[:, :: n + 1]
        f = finite[b]
        # a whole-array test first: where every pose is usable, no per-pose test, no masked copies
        every = bool(np.isfinite(q).all() and (diag > 0).all())
        f[:] = True if every else np.isfinite(q).all(axis=1) & (diag > 0).all(axis=1)
        Pf = Pb if every else Pb[f]
        exact = slice(None)
        if cap > 0.0 and n == 3:
            bound = 6.75 / np.maximum(_correlation_det3(Pf), 1e-300)  # 3 (3/2)^2 / det
            exact = ~(bound <= cap)
            if not exact.any():  # every pose proven well-conditioned (most live windows)
                out.append(bound)
                continue
            Pf = Pf[exact]
        db = np.sqrt(np.maximum(np.einsum("nii->ni", Pf), 1e-300))
        C = Pf / (db[:, :, None] * db[:, None, :])
        C = 0.5 * (C + np.swapaxes(C, 1, 2))
        eig = np.linalg.eigvalsh(C)
        cond = eig[:, -1] / np.maximum(eig[:, 0], 1e-300)
        if cap > 0.0 and n == 3:
            bound[exact] = cond
            cond = bound
        out.append(cond)
    return finite, np.concatenate(out)


def _correlation_det3(P) -> np.ndarray:
    """``det C`` of each 3 x 3 covariance of ``P`` (N, 3, 3; finite, positive diagonal) from
    its three correlations ``r`` (of the symmetric part, over the sigmas, so no product can
    overflow or vanish): ``1 + 2 r01 r02 r12 - r01^2 - r02^2 - r12^2``."""
    q = P.reshape(len(P), 9)
    s0, s1, s2 = np.sqrt(q[:, 0]), np.sqrt(q[:, 4]), np.sqrt(q[:, 8])
    r01 = 0.5 * (q[:, 1] + q[:, 3]) / s0 / s1  # one sigma at a time: |P01| / s0 <= s1
    r02 = 0.5 * (q[:, 2] + q[:, 6]) / s0 / s2
    r12 = 0.5 * (q[:, 5] + q[:, 7]) / s1 / s2
    return 1.0 + 2.0 * r01 * r02 * r12 - (r01 * r01 + r02 * r02 + r12 * r12)


def covariance_health(t, P, options: FilterOptions) -> list[Finding]:
    """Conditioning and growth of the pose covariances (SPD is :mod:`odofuse.status.findings`'s).

    The condition number is that of the correlation matrix (unit-free: metres and radians
    do not mix); growth is the position sigma over its running minimum, reported once it
    exceeds ``options.growth_factor``.
    """
    P = np.asarray(P, dtype=float)
    t = np.asarray(t, dtype=float)
    if P.size == 0:
        return []
    out = []
    finite, cond = _correlation_condition(P, cap=float(options.max_condition))
    if finite.any():
        bad = cond > options.max_condition
        if bad.any():
            idx = np.flatnonzero(finite)[bad]
            out.append(
                Finding(
                    "covariance",
                    f"{idx.size} pose covariance(s) ill-conditioned (correlation condition "
                    f"up to {_s(cond.max())} > {_s(options.max_condition)})",
                    t_start=float(t[idx[0]]),
                    t_end=float(t[idx[-1]]),
                    figure=float(cond.max()),
                )
            )
    sig = np.sqrt(np.maximum(P[:, 0, 0] + P[:, 1, 1], 0.0))
    sig = np.where(np.isfinite(sig), sig, np.inf)
    floored = np.maximum(sig, 1e-12)
    run_min = np.minimum.accumulate(floored)
    ratio = sig / run_min
    if ratio.size and ratio.max() > options.growth_factor:
        k = int(np.argmax(ratio))
        k0 = int(np.flatnonzero(floored[: k + 1] == run_min[k])[-1])
        out.append(
            Finding(
                "covariance_growth",
                f"position sigma grew {_s(ratio[k])}-fold ({_s(sig[k0])} -> {_s(sig[k])} m): "
                "the sensors stopped constraining the position",
                t_start=float(t[k0]),
                t_end=float(t[k]),
                figure=float(ratio[k]),
            )
        )
    return out


# ----------------------------------------------------------------------------- dead reckoning
def gyro_wheel_findings(t, dtheta_odo, var_odo, gyro_t, gyro_wz, gyro_sigma, options):
    """Windows in which the gyro and the wheels disagree about the heading change.

    Parameters
    ----------
    t : ndarray (N+1,)
        Odometry pose times (s).
    dtheta_odo, var_odo : ndarray (N,)
        Wheel heading change of each step (rad) and its variance (rad^2, error model).
    gyro_t, gyro_wz : ndarray (M,)
        Gyro times (s) and yaw rates (rad/s).
    gyro_sigma : float
        Gyro rate noise (rad/s per sample).
    options : DeadReckoningOptions

    Returns
    -------
    list of Finding
        One finding (the worst window, the count and the time covered) when any window of
        ``heading_window`` seconds fails the chi-square test on
        ``(Delta_gyro - Delta_wheels)^2 / (var_wheels + var_gyro + (bias_sigma T)^2)``.
    """
    from odofuse import chi2

    t = np.asarray(t, dtype=float)
    gt, gw = np.asarray(gyro_t, dtype=float), np.asarray(gyro_wz, dtype=float)
    if gt.size < 2 or t.size < 2:
        return []
    T = float(options.heading_window)
    edges = np.arange(max(t[0], gt[0]), min(t[-1], gt[-1]), T)
    if edges.size < 2:
        return []
    # Gyro heading (zero-order hold of each rate until the next sample) at the window edges.
    cum_g = np.concatenate([[0.0], np.cumsum(gw[:-1] * np.diff(gt))])
    k = np.clip(np.searchsorted(gt, edges, side="right") - 1, 0, gt.size - 1)
    th_g = cum_g[k] + gw[k] * (edges - gt[k])
    cum_o = np.concatenate([[0.0], np.cumsum(dtheta_odo)])
    cum_v = np.concatenate([[0.0], np.cumsum(var_odo)])
    th_o = np.interp(edges, t, cum_o)
    v_o = np.interp(edges, t, cum_v)
    rate = (gt.size - 1) / max(gt[-1] - gt[0], 1e-12)
    var = np.diff(v_o) + gyro_sigma**2 * T / rate + (options.bias_sigma * T) ** 2
    stat = np.diff(th_g - th_o) ** 2 / np.maximum(var, 1e-300)
    bound = chi2.ppf(1.0 - options.heading_alpha / stat.size, 1)
    flags = stat > bound
    spans = _spans(flags)
    if not spans:
        return []
    worst = int(np.argmax(stat))
    dis = float(np.diff(th_g - th_o)[worst])
    return [
        Finding(
            "gyro_wheels",
            f"gyro and wheel heading changes disagree in {int(flags.sum())} window(s) of "
            f"{T:g} s ({len(spans)} span(s)); worst {dis:+.3g} rad at {edges[worst]:.2f} s "
            f"({math.sqrt(stat[worst]):.1f} sigma): wheel slip or a gyro fault, dead reckoning "
            "keeps the error",
            sensor="gyro",
            t_start=float(edges[spans[0][0]]),
            t_end=float(edges[spans[-1][1] + 1]),
            figure=dis,
        )
    ]


# ----------------------------------------------------------------------------- collapse
#: A heading variance below this fraction of its running maximum since the last accepted
#: absolute measurement is a collapse (chosen a priori). Odometry and relative sensors (a
#: gyro's heading change) only let the heading variance grow, except for what a learnt gyro
#: bias takes back of the bias's share and what a gyro reading takes back of the odometry's
#: since the previous one (the running maximum is over the troughs, :func:`_troughs`); and
#: the sample variance of even 10 particles falls below 0.1 of the true one with probability
#: ~1e-5 (chi-square, 9 degrees of freedom). The position variance is not checked this way:
#: it honestly shrinks when the robot returns towards where a heading error began (the error
#: rotates the path about that point).
COLLAPSE_RATIO = 0.1


def _accepted_times(mon, streams, after: float = -math.inf) -> np.ndarray:
    """Times (s) after ``after`` of the accepted readings of ``streams`` in the monitor's
    record (stream by stream, each in time order); copies of the record's arrays, which keep
    growing (a numpy view would lock them), in a few microseconds where a Python loop over a
    20 Hz gyro's kept readings took 50.

    Each stream's record is in time order (a late reading replays from its step, cutting the
    record back first), so the readings after ``after`` are a suffix found by bisection: the
    live health's pass over its kept poses then copies what they span, not the whole run's
    record (which grows with the run)."""
    parts = []
    for s in streams:
        if s not in mon._t:
            continue
        times = mon._t[s]
        i = bisect.bisect_right(times, after)
        parts.append(np.array(times[i:], dtype=float)[np.array(mon._ok[s][i:]) == 1])
    return np.concatenate(parts) if parts else np.empty(0)


def _troughs(loc, t, log_v) -> np.ndarray:
    """``log_v`` with each pose's value replaced by the lowest of its interval between two
    readings of the relative (cloned) streams, e.g. a gyro's.

    A gyro measures the rotation since its previous reading, whose variance the odometry's
    predictions added in between: its update takes that share back, so the heading variance
    saws up between gyro readings and down at each. The running maximum of :func:`
    collapse_findings` runs over these troughs, not over the teeth: a skid steer turning on
    the spot at a square's corner, with its track scale still uncertain, rose 25x between
    two 20 Hz gyro readings and fell back at the next, and the check called that a collapse
    on 2 of 30 nominal logs (``benchmarks/bench_status.py``). A cloud or covariance that
    collapses stays low, and its troughs fall with it.
    """
    mon = loc.monitor
    streams = [s for s, m in loc.models.items() if hasattr(m, "clones") and m.clones()]
    rel = _accepted_times(mon, streams, t[0])  # those up to t[0] shift every index alike
    if not rel.size and not any(1 in mon._ok[s] for s in streams if s in mon._ok):
        return log_v  # no relative reading in the run: no intervals
    interval = np.searchsorted(np.unique(rel), t, side="right")
    starts = np.flatnonzero(np.r_[True, np.diff(interval) != 0])
    low = np.minimum.reduceat(log_v, starts)
    return np.repeat(low, np.diff(np.r_[starts, log_v.size]))


def _may_have_fallen(v: np.ndarray) -> bool:
    """False when no heading variance of ``v`` (N,) can be below :data:`COLLAPSE_RATIO` of a
    running maximum of :func:`collapse_findings`: each such maximum is at most ``max(v)``, so
    a smallest variance at or above ``COLLAPSE_RATIO * max(v)`` proves it. NaN: True (the
    exact check decides)."""
    return not v.min() >= COLLAPSE_RATIO * v.max()


def collapse_findings(loc, t, P) -> list[Finding]:
    """A heading variance that shrank with no absolute measurement to shrink it.

    A sample-based filter whose cloud loses its spread (resampling thinning a particle cloud
    the weights say nothing about) shows exactly that. Checked per span between accepted
    readings of the absolute streams (every stream without cloned states). The finding names
    one such span (the one with the deepest fall: from its first to its last pose below
    :data:`COLLAPSE_RATIO` of the running maximum) and the absolute streams' readings from
    that maximum to its end (none accepted, by construction), counted
    from the monitor's record of what arrived (issue 31: one finding once merged the falls of
    several spans into one window that held accepted GPS fixes).

    Parameters
    ----------
    loc : Localizer
        Its models (which streams are absolute) and monitor (accepted reading times).
    t : ndarray (N,)
        Pose times (s).
    P : ndarray (N, 3, 3)
        Pose covariances (world frame).
    """
    t, P = np.asarray(t, dtype=float), np.asarray(P, dtype=float)
    if t.size < 2:
        return []
    v = P[:, 2, 2]
    if not _may_have_fallen(v):  # the live health's usual case, in 3 us instead of 15
        return []
    mon = loc.monitor
    absolute = [
        s
        for s, m in loc.models.items()
        if not (m.clones() if hasattr(m, "clones") else {}) and s in mon._t
    ]
    # the span of each pose (readings up to t[0] would add the same count to every pose)
    seg = np.searchsorted(np.sort(_accepted_times(mon, absolute, t[0])), t, side="right")
    log_v = np.log(np.minimum(np.fmax(v, 1e-300), 1e300))  # nan and -inf: 1e-300
    offset = seg * 2000.0  # larger than any spread of log_v: a running max per span
    peak = np.maximum.accumulate(_troughs(loc, t, log_v) + offset) - offset
    bad = log_v < peak + math.log(COLLAPSE_RATIO)
    if not bad.any():
        return []
    idx = np.flatnonzero(bad)
    k = idx[int(np.argmin(log_v[idx] - peak[idx]))]
    drop = math.exp(log_v[k] - peak[k])
    same = np.flatnonzero(seg == seg[k])  # the poses of the worst fall's span
    before = same[same <= k]
    at_peak = before[int(np.argmax(log_v[before]))]
    fell = same[bad[same]]
    t0, t1 = float(t[at_peak]), float(t[fell[-1]])
    inside = []
    for s in absolute:
        tm = np.asarray(mon._t[s], dtype=float)
        ok = np.asarray(mon._ok[s], dtype=bool)
        w = (tm > t0) & (tm <= t1)
        inside.append(f"{s}: {int(np.count_nonzero(w & ok))} accepted of {int(w.sum())}")
    spans = len(set(seg[idx].tolist()))
    more = f"; {spans - 1} other span(s) fell too" if spans > 1 else ""
    return [
        Finding(
            "collapse",
            f"heading variance fell to {_s(v[k])} rad^2, {_s(drop)} of its "
            f"{_s(math.exp(peak[k]))} rad^2 at {t0:.2f} s, with no absolute measurement "
            f"accepted in between ({', '.join(inside) or 'no absolute stream'}): the "
            f"covariance collapsed and claims more than the sensors told{more}",
            t_start=float(t[fell[0]]),
            t_end=t1,
            figure=drop,
        )
    ]


# ----------------------------------------------------------------------------- learning
#: A heading sigma more than this multiple of what it would be with the gyro bias known as well
#: as at the end of the run: issue 10's own ratio for holding (within 2x of the smoother).
LEARNING_RATIO = 2.0
#: ... for more than this fraction of the run: issue 10's own bound for a score (nothing over
#: less than half of the estimate's span without a warning), as for an ``outage``.
LEARNING_FRACTION = 0.5
#: Relative change that starts a new record (one entry per 1 % of change of a variance, not
#: one per odometry step, so the record stays short; the span is found to that precision).
LEARNING_STEP = 0.01


def record_learning(rec, t: float, P, i: int) -> None:
    """Append the heading / bias covariance terms of ``P`` at ``t`` (s) to ``rec``.

    ``rec`` is four ``array("d")``: times, heading variance ``P_tt`` (rad^2), the part of it
    the bias explains ``P_tb^2 / P_bb`` (rad^2) and the bias variance ``P_bb`` (bias state
    ``i``). Piecewise constant: a new entry only when a term moved by more than
    :data:`LEARNING_STEP` (``P_tt`` and the explained part relative to ``P_tt``, ``P_bb``
    relative to itself). A replay (``t`` at or before the last entry, the Localizer's
    late-measurement window) first drops the entries it re-does.
    """
    vt, vb = float(P[2, 2]), float(P[i, i])
    record_learning_terms(rec, t, vt, float(P[2, i]) ** 2 / vb if vb > 0.0 else 0.0, vb)


def record_learning_terms(rec, t: float, vt: float, ve: float, vb: float) -> None:
    """:func:`record_learning` of the terms ``P_tt``, ``P_tb^2 / P_bb`` and ``P_bb`` (the
    compiled filters compute them in their kernel)."""
    times, ptt, expl, pbb = rec
    while times and times[-1] >= t:
        for a in rec:
            a.pop()
    if times:
        tol = LEARNING_STEP * ptt[-1]
        if (
            abs(vt - ptt[-1]) <= tol
            and abs(ve - expl[-1]) <= tol
            and abs(vb - pbb[-1]) <= LEARNING_STEP * pbb[-1]
        ):
            return
    times.append(t)
    ptt.append(vt)
    expl.append(ve)
    pbb.append(vb)


def learning_findings(state, sensor, rec, t0, t1, var_end) -> list[Finding]:
    """A heading that rested on a gyro bias the filter was still learning over most of the run.

    For a constant bias the batch smoother's variance of it is, at every time, the filter's
    final one (``var_end``: the smoothed estimate of a constant uses all the log, what the
    filter has at the end; with a random walk the smoothed variance inside the run is below
    it). Had the filter known the bias that well at time ``t``, its heading variance would
    have been (Gaussian conditioning on the bias)::

        P_tt - (P_tb^2 / P_bb) (1 - var_end / P_bb)

    Where its own ``P_tt`` exceeds that by :data:`LEARNING_RATIO` in sigma, the smoother of
    the same log knows the heading at least that much better through the bias alone, and the
    filter's pose there is expected to fall short of the smoother's, however consistent its
    innovations are (they are: the information was not there yet). A gyro bias learnt from
    the wheels and a coarse GPS is the case in point. Reported when that holds for more than
    :data:`LEARNING_FRACTION` of the run ``[t0, t1]`` (s); from the filter's own covariance.
    A note, never ``degraded`` (issue 25 item 2: accuracy against a smoother is advice): the
    covariance says it, so the estimate is honest (it fired on a nominal log whose EKF held
    at NEES 0.8 of its bound).

    Parameters
    ----------
    state, sensor : str
        Bias state name (``"gyro_bias"``) and its stream.
    rec : tuple of four sequences
        :func:`record_learning`'s record.
    t0, t1 : float
        The run's span (s).
    var_end : float
        The bias variance at ``t1`` ((rad/s)^2).
    """
    tr, ptt, expl, pbb = (np.asarray(a, dtype=float) for a in rec)
    if tr.size == 0 or not (t1 > t0) or not (var_end > 0.0) or not math.isfinite(var_end):
        return []
    gain = np.clip(1.0 - var_end / np.maximum(pbb, 1e-300), 0.0, 1.0)
    known = np.maximum(ptt - expl * gain, 0.0)
    above = ptt > LEARNING_RATIO**2 * known
    ends = np.append(tr[1:], t1)
    length = float(np.sum(np.clip(ends, t0, t1)[above] - np.clip(tr, t0, t1)[above]))
    if not length > LEARNING_FRACTION * (t1 - t0):
        return []
    last = float(ends[np.flatnonzero(above)[-1]])
    worst = float(np.sqrt(np.max(ptt[above] / np.maximum(known[above], 1e-300))))
    return [
        Finding(
            "learning",
            f"heading sigma above {LEARNING_RATIO:g}x (up to {worst:.3g}x) what it would be "
            f"with {state} known as at the end (sigma {_s(math.sqrt(var_end))}) for "
            f"{length:.1f} s of the run's {t1 - t0:.1f} s (until {last:.1f} s): the heading "
            "rested on a bias still being learnt, which a smoother of this log knows "
            "throughout; expect the pose there to fall well short of a smoother's (a note: "
            "the covariance says so)",
            sensor=sensor,
            t_start=float(max(tr[0], t0)),
            t_end=last,
            figure=length / (t1 - t0),
            degrades=False,
        )
    ]
