"""Self-checks of the filters without ground truth.

Their options (windows, false-alarm probabilities, recovery, slip) are declared once with the
filters' other options in :class:`odofuse.declarations.FilterOptions` (EKF, UKF, particle) and
:class:`odofuse.declarations.DeadReckoningOptions`. This module owns

* :class:`FilterMonitor`, fed every gated update by the streaming
  :class:`~odofuse.estimators.localizer.Localizer`: it says when a stream shows divergence (a
  run of consecutive rejections while the stream keeps arriving), computes the covariance
  inflation that makes the rejected innovation admissible (:func:`inflation_factor`), and
  turns what it saw into :class:`~odofuse.health.Finding` records (windowed NIS outside its
  chi-square band, rejection runs, recoveries, a sensor silent for most of the run, pose
  covariance conditioning and growth, calibration states that ran to their bounds or
  collapsed, a heading that rested on a gyro bias still being learnt over most of the run);
* :func:`slip_scale`, the robust (heavy-tailed) odometry rule used when a gyro is present;
* the track checks it calls live in :mod:`odofuse.estimators.pose_checks` (covariance
  health, collapse, and dead reckoning's gyro-vs-wheels tell-tale).

Thresholds are chosen a priori from statistics (chi-square quantiles, false-alarm
probabilities, window lengths counted in readings of the sensor concerned), never from
ground truth.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from odofuse.declarations import FilterOptions
from odofuse.estimators.pose_checks import (
    _s,
    _spans,
    collapse_findings,
    covariance_health,
    learning_findings,
    record_learning,
)
from odofuse.health import Finding, status_of
from odofuse.measurements import gate_threshold


# ----------------------------------------------------------------------------- recovery
def inflation_factor(y, S, R, dim: int, cap: float) -> float:
    """Scale ``lambda >= 1`` of the predicted measurement covariance that admits ``y``.

    With ``A = S - R`` the part of the innovation covariance that comes from the state,
    ``lambda`` solves ``y^T (lambda A + R)^-1 y = dim`` (the innovation becomes a typical,
    expected-value draw): the state covariance was ``lambda`` times too small to explain it.
    Bisection on ``log lambda``; ``cap`` when even that does not admit it.
    """
    y = np.atleast_1d(np.asarray(y, dtype=float))
    S = np.atleast_2d(np.asarray(S, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    A = 0.5 * ((S - R) + (S - R).T)

    def nis(lam):
        try:
            return float(y @ np.linalg.solve(lam * A + R, y))
        except np.linalg.LinAlgError:
            return math.inf

    if nis(1.0) <= dim:
        return 1.0
    if nis(cap) > dim:
        return float(cap)
    lo, hi = 0.0, math.log(cap)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if nis(math.exp(mid)) > dim:
            lo = mid
        else:
            hi = mid
    return float(math.exp(hi))


def slip_scale(
    disagreement: float, var_odo: float, var_ref: float, gate: float, run: float = 0.0
) -> float:
    """Robust odometry: the factor that widens one step's wheel input noise.

    ``disagreement`` (rad) is the gyro heading change minus the wheels' over the step,
    ``var_odo`` the wheels' heading variance of the step (rad^2) and ``var_ref`` that of the
    gyro's change (rate noise and bias uncertainty). When the disagreement fails the
    chi-square test ``d^2 > gate (var_odo + var_ref)`` the wheels slipped (the gyrodometry
    switching rule of ``002_88fc37db58155723.txt``, with a statistical threshold) and the
    step's wheel noise is widened (a heavy-tailed odometry model). Else 1.

    A slip lasts: the steps of one burst err alike, so their wheel errors are correlated, and
    widening each step to its own disagreement (``d^2``) would give the burst's accumulated
    translation error only ``sqrt(n)`` of the ``n`` sigmas it has. ``run`` is the summed
    disagreement ``D`` of the consecutive slipping steps just before this one; the step gets
    the variance that makes the run's accumulated wheel variance ``(D + d)^2`` (the summed
    heading disagreement is a one-sigma event, and so is the translation error the same
    slip caused), at least ``d^2``: factor ``max(d^2, (D + d)^2 - D^2) / var_odo``.
    """
    if not var_odo > 0.0:
        return 1.0
    d2 = disagreement * disagreement
    if d2 <= gate * (var_odo + var_ref):
        return 1.0
    total = run + disagreement
    return max(d2, total * total - run * run) / var_odo


# ----------------------------------------------------------------------------- monitor
def nis_keys(stream: str) -> str:
    """The config keys an innovation-band finding of ``stream`` points at."""
    if stream == "gyro" or stream.startswith("gyro_"):
        # the gyro's innovation covariance holds the wheels' heading noise (motion.k)
        return f"; keys: sensors.{stream}.sigma and motion.k (k_r, k_l)"
    return f"; keys: sensors.{stream}.sigma"


@dataclass(frozen=True)
class Health:
    """Live health of a streaming filter: :meth:`Localizer.health`'s answer."""

    status: str
    findings: tuple


@dataclass(frozen=True)
class _Recovery:
    stream: str
    t_first: float  # first rejected reading of the run
    t: float  # the reading that triggered the recovery
    factor: float
    readings: int


def outage_findings(s: str, ts, t0: float, t1: float, reject_run: int) -> list[Finding]:
    """A sensor silent for more than half of the run (the estimate is dead reckoning there).

    The longest span of the run ``[t0, t1]`` (pose times) without a reading of ``s`` (reading
    times ``ts``), counting a late start and an early end. The bound is issue 10's own for a
    score (no score over less than half of the estimate's span without a warning): over most
    of such a run the pose rests on odometry alone, a drift that no innovation or residual
    check can see while the sensor is away, so the run does not claim to be the fused
    estimate it was configured for. Used by the filters' monitor and the graph's checks.
    """
    ts = np.sort(np.asarray(ts, dtype=float))
    step = np.diff(ts)
    step = step[step > 0]
    if step.size == 0:  # fewer than two readings: no rate to miss (live start-up)
        return []
    edges = np.concatenate([[t0], ts[(ts > t0) & (ts < t1)], [t1]])
    gaps = np.diff(edges)
    k = int(np.argmax(gaps))
    # Also longer than reject_run readings of the stream: an outage, not its start-up.
    long = max(int(reject_run), 1) * float(np.median(step))
    if not (gaps[k] > 0.5 * (t1 - t0) and gaps[k] > long):
        return []
    return [
        Finding(
            "outage",
            f"no reading for {gaps[k]:.1f} s of the run's {t1 - t0:.1f} s "
            f"({ts.size} readings in all): over that span the estimate is dead reckoning",
            sensor=s,
            t_start=float(edges[k]),
            t_end=float(edges[k + 1]),
            figure=float(gaps[k]),
        )
    ]


class FilterMonitor:
    """Per-stream innovation bookkeeping of one filter, its recovery trigger and its findings.

    Parameters
    ----------
    options : KalmanOptions
    models : dict
        Stream -> bound measurement model (``dim``, ``gate``, calibration priors).
    """

    def __init__(self, options: FilterOptions, models: Mapping[str, object]) -> None:
        self.options = options
        self.dims = {s: int(m.dim) for s, m in models.items()}
        self.gates = {
            s: gate_threshold(getattr(m, "gate", None), int(m.dim)) for s, m in models.items()
        }
        self._t = {s: array("d") for s in models}
        self._nis = {s: array("d") for s in models}
        self._ok = {s: array("b") for s in models}
        self._floor = {s: 0 for s in models}  # rejections before this index are handled
        self.recoveries: list[_Recovery] = []
        self._priors = {}
        self._clones = set()
        for m in models.values():
            for s, (v, sd) in (m.calib_prior() if hasattr(m, "calib_prior") else {}).items():
                self._priors.setdefault(s, (float(v), float(sd)))
            self._clones |= set(m.clones() if hasattr(m, "clones") else {})

    # -- live ------------------------------------------------------------------------------
    def snapshot(self):
        """Cheap state token (list lengths) for the Localizer's late-measurement replay."""
        return {s: len(a) for s, a in self._t.items()}, dict(self._floor), len(self.recoveries)

    def restore(self, snap) -> None:
        lengths, floor, n_rec = snap
        for s, n in lengths.items():
            del self._t[s][n:], self._nis[s][n:], self._ok[s][n:]
        self._floor = dict(floor)
        del self.recoveries[n_rec:]

    def observe(self, stream: str, t: float, accepted: bool, nis: float) -> bool:
        """Record one gated update; True when the stream shows divergence (recovery due).

        Divergence: the last ``reject_run`` readings of the stream were all rejected. With a
        gate of probability ``p`` a consistent filter does that with probability
        ``(1 - p)^reject_run`` (1e-15 for 0.999 and 5): the filter, not the sensor, is off
        (or the sensor is broken for that long, which the findings then show).
        """
        self._t[stream].append(t)
        self._nis[stream].append(nis if math.isfinite(nis) else 1e300)
        self._ok[stream].append(1 if accepted else 0)
        if accepted or not self.options.recovery:
            return False
        ok, k = self._ok[stream], self.options.reject_run
        n = len(ok)
        if k < 1 or n - self._floor[stream] < k:
            return False
        return not any(ok[n - k :])

    def recovered(self, stream: str, factor: float) -> None:
        """Note a recovery triggered by the last reading of ``stream``."""
        n = len(self._t[stream])
        k = self.options.reject_run
        rec = _Recovery(stream, self._t[stream][n - k], self._t[stream][n - 1], factor, k)
        self.recoveries.append(rec)
        self._floor[stream] = n

    # -- findings --------------------------------------------------------------------------
    def findings(self, t, P, calibration) -> list[Finding]:
        """Everything the monitor noticed so far.

        Parameters
        ----------
        t : ndarray (N,)
            Pose times (s).
        P : ndarray (N, 3, 3)
            Pose covariances (world frame).
        calibration : dict
            State -> ``{"value", "sigma"}`` (the filter's current augmented states).
        """
        out: list[Finding] = []
        t = np.asarray(t, dtype=float)
        for s in self._t:
            out += self._nis_findings(s)
            out += self._run_findings(s)
            if t.size > 1:
                ts = np.frombuffer(self._t[s], dtype=float)
                out += outage_findings(s, ts, float(t[0]), float(t[-1]), self.options.reject_run)
        out += self._recovery_findings()
        out += covariance_health(t, P, self.options)
        out += self._calibration_findings(calibration)
        return out

    def _nis_findings(self, s: str) -> list[Finding]:
        from odofuse import chi2

        # Accepted readings only: gated outliers are the gate's business (rejection runs and
        # fractions report those); the gate at 0.999 barely truncates the chi-square law.
        ok = np.frombuffer(self._ok[s], dtype=np.int8) == 1
        nis = np.minimum(np.frombuffer(self._nis[s], dtype=float)[ok], 1e12)
        t = np.frombuffer(self._t[s], dtype=float)[ok]
        n, d, w = nis.size, self.dims[s], max(int(self.options.nis_window), 1)
        if n < w:
            return []
        c = np.concatenate([[0.0], np.cumsum(nis)])
        mean = (c[w:] - c[:-w]) / w  # window k covers readings k .. k+w-1
        # The sum of w consistent NIS values is chi-square with w*d degrees of freedom; the
        # band holds all n/w independent windows with probability 1 - nis_alpha.
        a = self.options.nis_alpha / max(n // w, 1)
        lo, hi = chi2.ppf(0.5 * a, w * d) / w, chi2.ppf(1.0 - 0.5 * a, w * d) / w
        out = []
        for flags, side, degrades in ((mean > hi, "above", True), (mean < lo, "below", False)):
            spans = _spans(flags)
            if not spans:
                continue
            inside = np.zeros(n, dtype=bool)  # readings inside a flagged window
            for a0, b in spans:
                inside[a0 : b + w] = True
            covered = sum(t[j1] - t[j0] for j0, j1 in _spans(inside))
            a0, b = max(spans, key=lambda ab: np.max(np.abs(mean[ab[0] : ab[1] + 1] - d)))
            worst = float(mean[a0 : b + 1].max() if side == "above" else mean[a0 : b + 1].min())
            what = (
                "the filter is overconfident or off"
                if side == "above"
                else "the filter is pessimistic (covariance larger than the errors)"
            )
            out.append(
                Finding(
                    "nis",
                    f"mean NIS over {w} readings {side} its band [{_s(lo)}, {_s(hi)}] "
                    f"(expected {d}) in {len(spans)} span(s), {covered:.1f} s in all; worst "
                    f"{_s(worst)}: {what}{nis_keys(s)}",
                    sensor=s,
                    t_start=float(t[a0]),
                    t_end=float(t[min(b + w - 1, n - 1)]),
                    figure=worst,
                    degrades=degrades,
                )
            )
        return out

    def _run_findings(self, s: str) -> list[Finding]:
        k = max(int(self.options.reject_run), 1)
        ok = np.frombuffer(self._ok[s], dtype=np.int8)
        if ok.size < k:
            return []
        spans = [(a, b) for a, b in _spans(ok == 0) if b - a + 1 >= k]
        if not spans:
            return []
        t = np.frombuffer(self._t[s], dtype=float)
        a, b = max(spans, key=lambda ab: t[ab[1]] - t[ab[0]])
        total = sum(b1 - a1 + 1 for a1, b1 in spans)
        return [
            Finding(
                "rejection_run",
                f"{len(spans)} run(s) of >= {k} consecutive rejections ({total} readings); "
                f"longest {b - a + 1} readings over {t[b] - t[a]:.2f} s",
                sensor=s,
                t_start=float(t[a]),
                t_end=float(t[b]),
                figure=float(b - a + 1),
            )
        ]

    def _recovery_findings(self) -> list[Finding]:
        out = []
        for s in sorted({r.stream for r in self.recoveries}):
            rs = [r for r in self.recoveries if r.stream == s]
            top = max(r.factor for r in rs)
            out.append(
                Finding(
                    "recovery",
                    f"diverged {len(rs)} time(s) ({rs[0].readings} readings in a row rejected); "
                    f"pose covariance inflated up to x{_s(top)} to admit the innovation, "
                    "measurements re-admitted",
                    sensor=s,
                    t_start=rs[0].t_first,
                    t_end=rs[-1].t,
                    figure=float(len(rs)),
                )
            )
        return out

    def _calibration_findings(self, calibration) -> list[Finding]:
        out = []
        k = self.options.calib_sigmas
        for s, est in (calibration or {}).items():
            if s in self._clones or s not in self._priors:
                continue
            v0, sd0 = self._priors[s]
            v, sd = float(est["value"]), float(est["sigma"])
            if sd0 > 0 and abs(v - v0) > k * sd0:
                out.append(
                    Finding(
                        "calibration",
                        f"{s} = {_s(v)} is {abs(v - v0) / sd0:.1f} prior sigmas from its prior "
                        f"{_s(v0)} (bound {k:g}): it ran to its bound, other errors leak into it",
                        sensor=s,
                        figure=v,
                    )
                )
            elif sd0 > 0 and sd < 1e-3 * sd0:
                out.append(
                    Finding(
                        "calibration",
                        f"{s} sigma {_s(sd)} collapsed below 1e-3 of its prior {_s(sd0)}",
                        sensor=s,
                        figure=sd,
                    )
                )
        return out


def health_of(findings) -> Health:
    """:class:`Health` of a list of findings."""
    return Health(status_of(findings), tuple(findings))


# ----------------------------------------------------------------------------- localizer
def localizer_findings(loc, t, P) -> list:
    """The Localizer monitor's findings plus its wheel-slip note."""
    from odofuse.health import Finding

    out = loc.monitor.findings(t, P, loc.calibration())
    out += collapse_findings(loc, t, P)
    if loc._bias_idx is not None and len(t) > 1:
        i = loc._bias_idx
        out += learning_findings(
            "gyro_bias",
            loc._slip_stream,
            loc._bias_record,
            float(t[0]),
            float(t[-1]),
            float(loc.backend.cov()[i, i]),
        )
    if loc.slip_steps:
        out.append(
            Finding(
                "slip",
                f"gyro and wheels disagreed on {loc.slip_steps} odometry step(s): the "
                "wheel noise of those steps was widened to cover it (robust odometry)",
                sensor=loc._slip_stream,
                figure=float(loc.slip_steps),
                degrades=False,
            )
        )
    return out


def setup_localizer(loc) -> None:
    """Recovery indices (pose and heading clones), gyro-bias index and the slip stream."""
    from odofuse.measurements import GyroYawRate, gate_threshold

    index: dict[str, int] = {}
    clones = []
    for m in loc.models.values():
        index.update(getattr(m, "calib_index", {}))
        clones += [s for s in (m.clones() if hasattr(m, "clones") else {})]
    # Recovery inflates the pose and its clones (a clone is a past copy of theta).
    loc._pose_idx = [0, 1, 2] + sorted({index[s] for s in clones if s in index})
    loc._bias_idx = index.get("gyro_bias")
    gyros = [s for s, m in loc.models.items() if isinstance(m, GyroYawRate)]
    on = loc.options.slip and gyros and loc._gyro_stream is None
    loc._slip_stream = gyros[0] if on else None
    loc._slip_gate = gate_threshold(loc.options.slip_gate, 1)
    loc.slip_steps = 0
    loc._slip_runs = {}  # step end time -> summed disagreement of its slip run (rad)
    # Heading and gyro-bias covariance over the run (pose_checks.record_learning), read where
    # robust odometry reads the bias: the ``learning`` check.
    loc._bias_record = tuple(array("d") for _ in range(4))


def recover(loc, stream, model, row) -> tuple[bool, float]:
    """Re-open after divergence: inflate the pose covariance, re-apply the reading."""
    y, S, R = loc.backend.last_innovation
    factor = inflation_factor(y, S, R, model.dim, loc.options.max_inflation)
    loc.backend.inflate(factor, loc._pose_idx)
    loc.monitor.recovered(stream, factor)
    return loc.backend.update(model, row)


def step_slip_scale(loc, t0: float, t1: float, u) -> float:
    """Input-noise factor of one odometry step (robust odometry, :func:`slip_scale`)."""
    g = loc._gyro_increment(t0, t1)
    if g is None or t1 <= t0:
        return 1.0
    model = loc.models[loc._slip_stream]
    delta, J = loc._increment(u)
    mm = loc.motion_model
    var_odo = float((J[2] ** 2) @ mm.errors.variances(mm.drive, u, t1 - t0))
    span = t1 - t0
    if loc._bias_idx is not None:
        bias = float(loc.backend.mean()[loc._bias_idx])
        cov = loc.backend.cov()
        var_b = float(cov[loc._bias_idx, loc._bias_idx])
        record_learning(loc._bias_record, t0, cov, loc._bias_idx)
    else:
        bias, var_b = 0.0, float(getattr(model, "bias_sigma", 0.0)) ** 2
    sigma = float(getattr(model, "sigma", 0.0))
    var_ref = (sigma**2 + var_b) * span**2
    d = g - bias * span - float(delta[2])
    runs = loc._slip_runs
    run = runs.get(t0, 0.0)
    scale = slip_scale(d, var_odo, var_ref, loc._slip_gate, run)
    if scale > 1.0:
        loc.slip_steps += 1
    runs[t1] = run + d if scale > 1.0 else 0.0
    if len(runs) > 4096:  # keep what a replay inside the late window can still ask for
        horizon = t1 - loc.late_window - 1.0
        for key in [k for k in runs if k < horizon]:
            del runs[key]
    return scale


# ----------------------------------------------------------------------------- bounded memory
def forget_readings(monitor: FilterMonitor, keep: int, snapshots) -> list:
    """Drop all but the last ``keep`` readings of each stream (and recoveries) of ``monitor``.

    For a live Localizer whose memory must stay flat: its findings then cover the readings
    kept. Readings that a snapshot still refers to (a replay may restore it) are kept too.

    Parameters
    ----------
    monitor : FilterMonitor
    keep : int
        Readings to keep per stream.
    snapshots : iterable
        :meth:`FilterMonitor.snapshot` tokens still in use.

    Returns
    -------
    list
        The same tokens, re-expressed for the shortened records (same order).
    """
    snaps = list(snapshots)
    drop = {}
    for s, a in monitor._t.items():
        lowest = min((lengths[s] for lengths, _, _ in snaps), default=len(a))
        drop[s] = max(0, min(len(a) - keep, lowest))
    for s, k in drop.items():
        if k:
            del monitor._t[s][:k], monitor._nis[s][:k], monitor._ok[s][:k]
            monitor._floor[s] = max(0, monitor._floor[s] - k)
    n_rec = min((n for _, _, n in snaps), default=len(monitor.recoveries))
    gone = max(0, min(len(monitor.recoveries) - keep, n_rec))
    del monitor.recoveries[:gone]
    return [
        (
            {s: n - drop[s] for s, n in lengths.items()},
            {s: max(0, f - drop[s]) for s, f in floor.items()},
            n - gone,
        )
        for lengths, floor, n in snaps
    ]
