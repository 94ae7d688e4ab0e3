"""The filters' monitor: the per-stream record of every gated update, the recovery after
divergence, and the findings of a Localizer's run.

Their options (windows, false-alarm probabilities, recovery, slip) are declared once with the
filters' other options in :class:`odofuse.declarations.FilterOptions` (EKF, UKF, particle) and
:class:`odofuse.declarations.DeadReckoningOptions`. This module owns

* :class:`FilterMonitor`, fed every gated update by the streaming
  :class:`~odofuse.estimators.localizer.Localizer`: it records each stream's readings, feeds
  them to the streaming checks (:mod:`odofuse.status.streaming`: NIS windows with persistence
  and hysteresis, the innovation-mean scan, rejection runs and counts, outages; O(1) per
  reading), says when a stream shows divergence (a run of consecutive rejections while the
  stream keeps arriving), computes the covariance inflation that makes the rejected
  innovation admissible (:func:`inflation_factor`), and turns what it saw into
  :class:`~odofuse.status.findings.Finding` records (with recoveries, pose covariance
  conditioning and growth, and calibration states that ran to their bounds or collapsed);
* :class:`LiveHealth`, :meth:`Localizer.health
  <odofuse.estimators.localizer.Localizer.health>`'s answer;
* the Localizer's side of it: :func:`setup_localizer`, :func:`recover`,
  :func:`localizer_findings` (with the track checks of :mod:`odofuse.status.pose_checks`:
  collapse, and the gyro bias still being learnt) and :func:`forget_readings` (bounded memory).

The minimal detectable errors are in :mod:`odofuse.status.mde`, robust odometry (the wheels
against the gyro) in :mod:`odofuse.status.slip`.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from odofuse.declarations import FilterOptions
from odofuse.measurements import gate_threshold
from odofuse.status.findings import Finding
from odofuse.status.pose_checks import (
    _s,
    collapse_findings,
    covariance_health,
    learning_findings,
)
from odofuse.status.slip import slip_note
from odofuse.status.streaming import (
    StreamState,
    advance,
    end_count,
    end_scan,
    live_findings,
    outage_from_state,
)


# -------------------------------------------------------------------- recovery
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


@dataclass(frozen=True)
class LiveHealth:
    """Live health of a streaming filter: :meth:`Localizer.health`'s answer.

    Attributes
    ----------
    status : str
        ``"ok"`` or ``"degraded"`` *now*: degraded while a check is failing (after its
        persistence, until its hysteresis lets it recover; docs/filters.md, "Live health").
    run_status : str
        What the offline run of the log so far would say of it: ``"degraded"`` when any
        degrading finding was raised at any time of the run (``status_of(findings)``).
    findings : tuple of odofuse.status.findings.Finding
        Everything noticed so far, the episodes that are over included (their time spans).
    test_ratios : dict
        Sensor -> the last reading's innovation test statistic (NIS) over its gate bound
        (PX4 EKF2's test ratio: above 1 the reading was rejected; 0 without a gate).
    nis_ratios : dict
        Sensor -> the last complete NIS window's mean over its chi-square bound (above 1
        the window failed; ``nan`` before the first window is complete).
    mean_ratios : dict
        Sensor -> the innovation-mean scan's last evaluation over its bound (above 1 the
        window's mean innovation is off zero; ``nan`` before the first), for every stream
        (a gyro's over its blocks: :data:`~odofuse.status.streaming.MEAN_BLOCK_S`).
    t : float
        Filter time (s) the answer is for.
    """

    status: str
    run_status: str
    findings: tuple
    test_ratios: dict
    nis_ratios: dict
    mean_ratios: dict
    t: float


@dataclass(frozen=True)
class _Recovery:
    stream: str
    t_first: float  # first rejected reading of the run
    t: float  # the reading that triggered the recovery
    factor: float
    readings: int


# --------------------------------------------------------------------- monitor
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
        #: The innovation-mean scan tests every stream; its records keep ``dim`` whitened
        #: values a reading. The streams measured against a heading clone (a gyro's rate
        #: against the wheels' heading change since its previous reading) are scanned in
        #: blocks of :data:`~odofuse.status.streaming.MEAN_BLOCK_S`.
        self.rate_streams = frozenset(
            s for s, m in models.items() if hasattr(m, "clones") and m.clones()
        )
        self._white = {s: array("d") for s in models}
        self._floor = {s: 0 for s in models}  # rejections before this index are handled
        self.live = {s: StreamState() for s in models}  # the streaming checks (advance)
        self._cursor = {s: 0 for s in models}  # readings of the record fed to advance
        self.recoveries: list[_Recovery] = []
        self._priors = {}
        self._clones = set()
        #: The calibration drift check (:class:`odofuse.status.drift.Drift`), set by the
        #: Localizer of an EKF or UKF with calibration states; None otherwise.
        self.drift = None
        for m in models.values():
            for s, (v, sd) in (m.calib_prior() if hasattr(m, "calib_prior") else {}).items():
                self._priors.setdefault(s, (float(v), float(sd)))
            self._clones |= set(m.clones() if hasattr(m, "clones") else {})

    # -- live ------------------------------------------------------------------------------
    def snapshot(self):
        """Cheap state token (list lengths, the streaming checks' immutable states) for the
        Localizer's late-measurement replay."""
        self.catch_up()
        lengths = {s: len(a) for s, a in self._t.items()}
        n_drift = len(self.drift) if self.drift is not None else 0
        return lengths, dict(self._floor), len(self.recoveries), dict(self.live), n_drift

    def restore(self, snap) -> None:
        lengths, floor, n_rec, live, n_drift = snap
        for s, n in lengths.items():
            del self._t[s][n:], self._nis[s][n:], self._ok[s][n:]
            del self._white[s][n * self.dims[s] :]
        self._floor = dict(floor)
        del self.recoveries[n_rec:]
        self.live = dict(live)
        self._cursor = dict(lengths)
        if self.drift is not None:
            self.drift.truncate(n_drift)

    def catch_up(self) -> None:
        """Feed the streaming checks the readings recorded without :meth:`observe` (the
        compiled offline EKF fills the record in one go); O(1) per reading."""
        for s, n in self._cursor.items():
            if n < len(self._t[s]):
                self._advance(s, n)

    def _advance(self, s: str, n: int) -> None:
        st, gate, d, opts = self.live[s], self.gates[s], self.dims[s], self.options
        t, nis, ok = self._t[s], self._nis[s], self._ok[s]
        wy, rate = self._white[s], s in self.rate_streams
        for j in range(n, len(t)):
            white = None if ok[j] != 1 else tuple(wy[j * d : (j + 1) * d])
            st = advance(st, t[j], ok[j] == 1, nis[j], gate, d, opts, white, rate)
        self.live[s] = st
        self._cursor[s] = len(t)

    def end(self) -> None:
        """The run is over: each stream's innovation-mean scan and rejection count evaluate
        their last windows (:func:`~odofuse.status.streaming.end_scan`,
        :func:`~odofuse.status.streaming.end_count`); calling it again changes nothing."""
        self.catch_up()
        for s, st in self.live.items():
            st = end_scan(st, self.options, self.dims[s], s in self.rate_streams)
            self.live[s] = end_count(st, self.options, self.gates[s], self.dims[s])

    def failing(self) -> list[str]:
        """The streams whose checks are failing now (persistence reached, not recovered)."""
        self.catch_up()
        return [s for s, st in self.live.items() if st.failing or st.mfailing or st.rfailing]

    def observe(self, stream: str, t: float, accepted: bool, nis: float, white=None) -> bool:
        """Record one gated update; True when the stream shows divergence (recovery due).

        Divergence: the last ``reject_run`` readings of the stream were all rejected. With a
        gate of probability ``p`` a consistent filter does that with probability
        ``(1 - p)^reject_run`` (1e-15 for 0.999 and 5): the filter, not the sensor, is off
        (or the sensor is broken for that long, which the findings then show). ``white``:
        the reading's whitened innovation (:func:`~odofuse.status.streaming.whiten`; None: not
        known, the scan skips the reading).
        """
        self._t[stream].append(t)
        self._nis[stream].append(nis if math.isfinite(nis) else 1e300)
        self._ok[stream].append(1 if accepted else 0)
        d = self.dims[stream]
        self._white[stream].extend(
            white if white is not None and len(white) == d else (math.nan,) * d
        )
        self._advance(stream, self._cursor[stream])
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
    def findings(self, t, P, calibration, span=None) -> list[Finding]:
        """Everything the monitor noticed so far.

        Parameters
        ----------
        t : ndarray (N,)
            Pose times (s).
        P : ndarray (N, 3, 3)
            Pose covariances (world frame).
        calibration : dict
            State -> ``{"value", "sigma"}`` (the filter's current augmented states).
        span : tuple (t0, t1), optional
            The run's time span (s) for the outage check; by default ``t[0], t[-1]``.
        """
        t = np.asarray(t, dtype=float)
        out = self.stream_findings(span or ((float(t[0]), float(t[-1])) if t.size else None))
        out += covariance_health(t, P, self.options)
        out += self._calibration_findings(calibration)
        out += self.drift.findings() if self.drift is not None else []
        return out

    def stream_findings(self, span, outage: bool = True) -> list[Finding]:
        """The streaming checks' findings (:func:`~odofuse.status.streaming.live_findings`) and
        the recoveries; O(1) per stream. ``span`` ``(t0, t1)`` is the run's time span (None: no
        outage check)."""
        self.catch_up()
        out: list[Finding] = []
        t0, t1 = span if span is not None else (math.nan, math.nan)
        for s, st in self.live.items():
            out += live_findings(s, st, t0, t1, self.options, self.dims[s], outage, self.gates[s])
        out += self._recovery_findings()
        return out

    def outage_findings(self, span) -> list[Finding]:
        """The outage check alone over the run ``span`` ``(t0, t1)`` (it moves with time)."""
        self.catch_up()
        reject_run = self.options.reject_run
        return [
            f for s, st in self.live.items() for f in outage_from_state(s, st, *span, reject_run)
        ]

    def _recovery_findings(self) -> list[Finding]:
        if not self.recoveries:  # the usual answer, asked at every health() call
            return []
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


# ------------------------------------------------------------------- localizer
def localizer_findings(loc, t, P) -> list:
    """The Localizer's findings over the poses ``t``, ``P`` (the offline run's): the monitor's
    (streaming checks over the whole run, covariance conditioning and growth, calibration),
    collapse, gyro-bias learning and the wheel-slip note."""
    out = loc.monitor.findings(t, P, loc.calibration(), span=(loc.t_start, loc.t))
    out += collapse_findings(loc, t, P) + learning_of(loc, t) + slip_note(loc)
    return out


def learning_of(loc, t) -> list:
    """The ``learning`` check of the gyro bias over the run up to the pose times ``t``."""
    if loc._bias_idx is None or len(t) <= 1:
        return []
    i = loc._bias_idx
    return learning_findings(
        "gyro_bias",
        loc._slip_stream,
        loc._bias_record,
        float(t[0]),
        float(t[-1]),
        float(loc.backend.cov()[i, i]),
    )


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
    # (gate, gyro sigma, bias variance when the bias is not a state) of step_slip_scale
    gyro = loc.models[gyros[0]] if on else None
    loc._slip_params = np.array(
        [
            gate_threshold(loc.options.slip_gate, 1),
            float(getattr(gyro, "sigma", 0.0)),
            float(getattr(gyro, "bias_sigma", 0.0)) ** 2,
        ]
    )
    loc.slip_steps = 0
    loc._slip_runs = {}  # step end time -> summed disagreement of its slip run (rad)
    loc._slip_starts = {}  # step end time -> start time of its slip run (s)
    loc._slip_longest = (0.0, 0.0)  # (start, end) of the longest slip run (s)
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


# -------------------------------------------------------------- bounded memory
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
    monitor.catch_up()  # the streaming checks have seen every reading that goes
    drop = {}
    for s, a in monitor._t.items():
        lowest = min((lengths[s] for lengths, *_ in snaps), default=len(a))
        drop[s] = max(0, min(len(a) - keep, lowest))
    for s, k in drop.items():
        if k:
            del monitor._t[s][:k], monitor._nis[s][:k], monitor._ok[s][:k]
            del monitor._white[s][: k * monitor.dims[s]]
            monitor._floor[s] = max(0, monitor._floor[s] - k)
            monitor._cursor[s] -= k
    n_rec = min((n for _, _, n, *_ in snaps), default=len(monitor.recoveries))
    gone = max(0, min(len(monitor.recoveries) - keep, n_rec))
    del monitor.recoveries[:gone]
    return [
        (
            {s: n - drop[s] for s, n in lengths.items()},
            {s: max(0, f - drop[s]) for s, f in floor.items()},
            n - gone,
            live,
            n_drift,
        )
        for lengths, floor, n, live, n_drift in snaps
    ]
