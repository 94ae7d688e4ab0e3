"""Self-checks of the filters without ground truth.

Their options (windows, false-alarm probabilities, recovery, slip) are declared once with the
filters' other options in :class:`odofuse.declarations.FilterOptions` (EKF, UKF, particle) and
:class:`odofuse.declarations.DeadReckoningOptions`. This module owns

* :class:`FilterMonitor`, fed every gated update by the streaming
  :class:`~odofuse.estimators.localizer.Localizer`: it says when a stream shows divergence (a
  run of consecutive rejections while the stream keeps arriving), computes the covariance
  inflation that makes the rejected innovation admissible (:func:`inflation_factor`), and
  turns what it saw into :class:`~odofuse.status.findings.Finding` records (windowed NIS outside its
  chi-square band, rejection runs, recoveries, a sensor silent for most of the run, pose
  covariance conditioning and growth, calibration states that ran to their bounds or
  collapsed, a heading that rested on a gyro bias still being learnt over most of the run);
* the streaming checks (:func:`advance`: test ratio, NIS windows with persistence and
  hysteresis, the innovation-mean scan, rejection runs, reading times; O(1) per reading)
  that both
  :meth:`Localizer.health <odofuse.estimators.localizer.Localizer.health>` (a
  :class:`LiveHealth`) and the offline result read, and the minimal detectable errors of
  every gate, NIS window and scan (:func:`gate_mde`, :func:`window_mde`, :func:`mean_mde`,
  :func:`mde_of`);
* :func:`slip_scale`, the robust (heavy-tailed) odometry rule used when a gyro is present;
* the track checks it calls live in :mod:`odofuse.status.pose_checks` (covariance
  health, collapse, and dead reckoning's gyro-vs-wheels tell-tale).

Thresholds are chosen a priori from statistics (chi-square quantiles, false-alarm
probabilities, window lengths counted in readings of the sensor concerned), never from
ground truth.
"""

from __future__ import annotations

import functools
import math
from array import array
from collections.abc import Mapping
from dataclasses import dataclass
from statistics import NormalDist
from typing import NamedTuple

import numpy as np

from odofuse.declarations import FilterOptions
from odofuse.measurements import gate_threshold
from odofuse.status.findings import Finding
from odofuse.status.pose_checks import (
    _s,
    collapse_findings,
    covariance_health,
    learning_findings,
    record_learning,
    record_learning_terms,
)


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
        (a gyro's over its blocks: :data:`MEAN_BLOCK_S`).
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


# ----------------------------------------------------------------------------- live checks
class _Live(NamedTuple):
    """The streaming checks of one stream: O(1) work per reading, immutable (a snapshot for
    the Localizer's replay is a reference). Fed by :func:`advance`."""

    n: int = 0  # readings seen
    t_first: float = math.nan
    t_last: float = math.nan
    gap: float = 0.0  # longest time between two consecutive readings
    gap_t0: float = math.nan
    ratio: float = 0.0  # the last reading's NIS over its gate
    wsum: float = 0.0  # NIS of the accepted readings of the open window, summed
    wn: int = 0
    wt0: float = math.nan  # time of the open window's first reading
    k: int = 0  # complete windows
    wratio: float = math.nan  # the last complete window's mean over its upper bound
    bad: int = 0  # consecutive windows above their band
    bad_t0: float = math.nan
    bad_worst: float = 0.0
    low: int = 0  # consecutive windows below their band
    good: int = 0  # consecutive windows inside their band while failing
    failing: bool = False  # persistence reached, hysteresis not yet satisfied
    episodes: int = 0  # times the NIS check started failing
    ep_t0: float = math.nan
    ep_t1: float = math.nan
    ep_worst: float = 0.0
    low_episodes: int = 0
    low_t0: float = math.nan
    low_t1: float = math.nan
    low_worst: float = math.inf
    run: int = 0  # consecutive rejections now
    run_t0: float = math.nan
    runs: int = 0  # runs of >= reject_run rejections
    run_total: int = 0
    longest: int = 0
    long_t0: float = math.nan
    long_t1: float = math.nan
    tsum: float = 0.0  # NIS of every accepted reading, summed (the run's NIS test)
    tn: int = 0
    # The innovation-mean scan (absolute streams; :func:`mean_bound`)
    mwin: tuple = ()  # the last nis_window accepted readings' (t, whitened innovation)
    mk: int = 0  # evaluations of the scan
    mratio: float = math.nan  # the last evaluation's statistic over its bound
    mhits: int = 0  # evaluations above their bound
    m_t0: float = math.nan  # first window above its bound: its first reading's time
    m_t1: float = math.nan  # last window above its bound: its last reading's time
    mworst: float = 0.0  # the largest statistic over its bound
    mfailing: bool = False  # above its bound now (hysteresis: one window of readings)
    mgood: int = 0  # consecutive evaluations inside the bound while failing
    # A rate stream's readings enter the scan in blocks of MEAN_BLOCK_S (:func:`_rate_block`)
    bsum: tuple = ()  # the open block's summed whitened innovations
    bn: int = 0  # readings in the open block
    bt0: float = math.nan  # time of its first reading
    blen: int = 0  # readings in the last closed block (its MDE)
    bk: int = 0  # blocks closed
    # The rejection count (:func:`_count`): the last nis_window readings' gate decisions
    rk: int = 0  # evaluations
    rhits: int = 0  # evaluations at or above their bound
    r_t0: float = math.nan  # first window at or above its bound: its first rejection's time
    r_t1: float = math.nan
    rworst: int = 0  # the most rejections in a window that fired
    rbound: int = 0  # the bound of that window
    rfailing: bool = False
    rgood: int = 0
    rtimes: tuple = ()  # (index, time) of the rejected readings among the last nis_window


def _share(block: int, alpha: float) -> float:
    """One test's share of ``alpha`` in block ``block`` of an alpha-spending schedule over a
    run of any length: the tests ``2^b <= k < 2^(b+1)`` of block ``b`` share
    ``alpha * 6 / (pi^2 (b + 1)^2)`` (the blocks' shares sum to ``alpha``), ``2^-b`` each."""
    return alpha * 6.0 / (math.pi**2 * (block + 1) ** 2) / 2**block


def _block(k: int) -> int:
    """The block ``b`` (``2^b <= k < 2^(b+1)``) of the ``k``-th (1-based) test."""
    return max(int(k), 1).bit_length() - 1


@functools.lru_cache(maxsize=4096)
def _band(block: int, w: int, d: int, alpha: float, persist: int) -> tuple[float, float, float]:
    """``(lo, hi, a)``: the band of a window's mean NIS and its per-window probability ``a``.

    Alpha spending over a run of any length: the windows ``2^b <= k < 2^(b+1)`` of block
    ``b`` share ``alpha * 6 / (pi^2 (b + 1)^2)`` (the blocks' shares sum to ``alpha``); a check
    fails on ``persist`` consecutive windows, so one window's probability is that share's
    per-window part to the power ``1 / persist`` (consistent windows are independent).
    """
    q = _share(block, alpha)
    a = q ** (1.0 / persist)
    from odofuse import chi2

    lo, hi = chi2.ppf([a, 1.0 - a], w * d) / w
    return float(lo), float(hi), a


def window_band(k: int, w: int, d: int, alpha: float, persist: int) -> tuple[float, float, float]:
    """``(lo, hi, a)`` of the ``k``-th (1-based) window of ``w`` readings of dimension ``d``."""
    return _band(_block(k), int(w), int(d), float(alpha), int(persist))


def mean_stride(w: int) -> int:
    """Readings between two evaluations of the innovation-mean scan of windows of ``w``."""
    return max(int(w) // 4, 1)


def _still_failing(good: int, w: int, stride: int) -> tuple[bool, int]:
    """``(failing, good)`` of a failing scan or count after one more evaluation inside its
    bound (``good`` such evaluations before it, one every ``stride`` readings): it recovers
    once a whole window of ``w`` new readings is inside."""
    good += 1
    return (False, 0) if good * stride >= w else (True, good)


@functools.lru_cache(maxsize=4096)
def _mean_bound(block: int, d: int, alpha: float) -> tuple[float, float]:
    """``(bound, a)`` of the scan's evaluations ``2^b <= j < 2^(b+1)`` (block ``b``): the
    ``1 - a`` quantile of chi-square(``d``), ``a`` the evaluation's :func:`_share` (the NIS
    windows' spending, one evaluation at a time: Bonferroni, valid however the overlapping
    windows are correlated)."""
    a = _share(block, alpha)
    from odofuse import chi2

    return float(chi2.ppf(1.0 - a, d)), a


def mean_bound(j: int, d: int, alpha: float) -> tuple[float, float]:
    """``(bound, a)`` of the ``j``-th (1-based) evaluation of the innovation-mean scan."""
    return _mean_bound(_block(j), int(d), float(alpha))


@functools.lru_cache(maxsize=256)
def reject_probability(gate: float, d: int) -> float:
    """The probability that a consistent filter's reading fails its gate ``gate`` (NIS
    threshold) in ``d`` dimensions: ``P(chi2_d > gate)``; 0 without a gate."""
    if not math.isfinite(gate):
        return 0.0
    from scipy.special import gammaincc

    return float(gammaincc(0.5 * d, 0.5 * gate))


def count_probability(gate: float, d: int, gross: float) -> float:
    """The rejection count's null: the probability that a reading of a consistent filter's
    stream fails its gate when a share ``gross`` (``gross_fraction``) of the stream is gross,
    far beyond the gate (Huber's contaminated model: a real GNSS receiver has a few fixes tens
    of metres off, which the gate is there to set aside): ``p + (1 - p) gross``, ``p``
    :func:`reject_probability`; 0 without a gate."""
    p = reject_probability(gate, d)
    return p + (1.0 - p) * float(gross) if p > 0.0 else 0.0


@functools.lru_cache(maxsize=4096)
def _count_bound(block: int, w: int, p: float, alpha: float) -> tuple[int, float]:
    """``(k, a)``: the fewest rejections among ``w`` readings that fire the rejection count at
    an evaluation of block ``b`` (its :func:`_share` ``a``): the smallest ``k`` with
    ``P(Binomial(w, p) >= k) <= a``, ``p`` the gate's rejection probability (``w + 1``: never)."""
    a = _share(block, alpha)
    tail = 1.0
    for k in range(w + 1):
        if tail <= a:
            return k, a
        tail -= math.comb(w, k) * p**k * (1.0 - p) ** (w - k)
    return w + 1, a


def count_bound(j: int, w: int, p: float, alpha: float) -> tuple[int, float]:
    """``(k, a)`` of the ``j``-th (1-based) evaluation of the rejection count."""
    return _count_bound(_block(j), int(w), float(p), float(alpha))


def _count(
    st: _Live, kw: dict, t: float, ok: bool, gate: float, d: int, w: int, stride: int, opts
) -> None:
    """The rejection count after one gated reading (into ``kw``): every ``stride``
    (:func:`mean_stride`) readings, the rejections among the last ``w`` against the binomial
    bound of :func:`count_probability` (:func:`count_bound`). A consistent filter rejects a
    reading with probability ``1 - gate`` (1e-3), independently of the others, and a real
    sensor adds its few gross readings (``gross_fraction``, 3 %: two gross GNSS fixes in a
    window are not a fault); a burst that the gate rejects one in two (GPS multipath at 4
    sigma) fails it within a window, where the runs of ``reject_run`` consecutive rejections
    need them in a row."""
    n = st.n + 1  # this reading's index (1-based)
    rej = st.rtimes if ok else st.rtimes + ((n, t),)
    if rej and rej[0][0] <= n - w:  # rejections are rare: O(1) a reading
        rej = tuple(e for e in rej if e[0] > n - w)
    if rej is not st.rtimes:
        kw["rtimes"] = rej
    if n < w or (n - w) % stride:
        return
    p = count_probability(gate, d, opts.gross_fraction)
    if p <= 0.0:
        return
    j = st.rk + 1
    k, _ = count_bound(j, w, p, opts.nis_alpha)
    count = len(rej)
    kw["rk"] = j
    if count >= k:
        kw.update(rhits=st.rhits + 1, rfailing=True, rgood=0, r_t1=t)
        if count > st.rworst:
            kw.update(rworst=count, rbound=k)
        if st.rhits == 0 and rej:
            kw["r_t0"] = rej[0][1]
    elif st.rfailing:
        kw["rfailing"], kw["rgood"] = _still_failing(st.rgood, w, stride)


def whiten(y, S) -> tuple | None:
    """``L^-1 y`` with ``S = L L^T`` (lower Cholesky) as a tuple, or None when ``S`` is not
    positive definite; closed form for ``d <= 2`` (the compiled kernels' ``_whiten`` is the
    same formula: the scan's sums must not depend on the path)."""
    y = np.atleast_1d(np.asarray(y, dtype=float))
    S = np.atleast_2d(np.asarray(S, dtype=float))
    if y.size == 1:
        s00 = float(S[0, 0])
        return (float(y[0]) / math.sqrt(s00),) if s00 > 0.0 else None
    if y.size == 2:
        s00, s10, s11 = float(S[0, 0]), float(S[1, 0]), float(S[1, 1])
        if not s00 > 0.0:
            return None
        l00 = math.sqrt(s00)
        l10 = s10 / l00
        r = s11 - l10 * l10
        if not r > 0.0:
            return None
        v0 = float(y[0]) / l00
        return v0, (float(y[1]) - l10 * v0) / math.sqrt(r)
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return None
    return tuple(float(v) for v in np.linalg.solve(L, y))


def _usable(white, d: int) -> bool:
    """Whether ``white`` is a finite whitened innovation of dimension ``d`` (the scan's and a
    rate stream's blocks skip any other reading)."""
    return white is not None and len(white) == d and all(math.isfinite(v) for v in white)


def _scan(
    st: _Live, kw: dict, t: float, white, w: int, d: int, stride: int, opts, n=None, t0=None
) -> None:
    """The innovation-mean scan after one accepted reading with whitened innovation
    ``white`` (into ``kw``): every ``stride`` (:func:`mean_stride`) readings, the last ``w``
    whitened innovations' sum ``s`` gives ``|s|^2 / w``, chi-square(``d``) under the filter's
    own model, against :func:`mean_bound`. It sees a bias that the NIS hardly does: a 1 m offset
    under a 2 m GPS adds a quarter to each NIS but shares its sign over tens of readings.
    A rate stream passes its blocks instead (:func:`_rate_block`): ``n`` the block's count, ``t0``
    its first reading's time."""
    if not _usable(white, d):
        return
    win = st.mwin + ((t if t0 is None else t0, *white),)
    if len(win) > w:
        win = win[1:]
    kw["mwin"] = win
    n = st.tn + 1 if n is None else n
    if len(win) < w or (n - w) % stride:
        return
    j = st.mk + 1
    sums = [math.fsum(e[1 + i] for e in win) for i in range(d)]
    stat = math.fsum(v * v for v in sums) / w
    bound, _ = mean_bound(j, d, opts.nis_alpha)
    ratio = stat / bound
    kw.update(mk=j, mratio=ratio)
    if ratio > 1.0:
        kw.update(mhits=st.mhits + 1, mfailing=True, mgood=0, m_t1=t)
        kw["mworst"] = max(st.mworst, ratio)
        if st.mhits == 0:
            kw["m_t0"] = win[0][0]
    elif st.mfailing:
        kw["mfailing"], kw["mgood"] = _still_failing(st.mgood, w, stride)


#: s: a rate stream's whitened innovations (a gyro's: :attr:`FilterMonitor.rate_streams`) enter the
#: innovation-mean scan summed over blocks of at least this time, so that its window of
#: ``nis_window`` blocks spans as long as a 1 Hz sensor's window of ``nis_window`` readings. A
#: gyro's innovation is its rate against the wheels' heading change over one reading's interval,
#: whose noise the wheels dominate (docs/trust.md, "The gyro in the innovation-mean scan"): a
#: window of 20 readings at 20 Hz sees a bias of a sixth of that noise only after 36 windows.
MEAN_BLOCK_S = 1.0


def _rate_block(st: _Live, kw: dict, t: float, white, d: int):
    """Add one accepted reading's whitened innovation to the open block (into ``kw``);
    returns the block's normalised sum ``sum / sqrt(n)`` (``N(0, I)`` under the filter's own
    model, as one reading's) when the block reaches :data:`MEAN_BLOCK_S`, else None."""
    if not _usable(white, d):
        return None
    if st.bn == 0:
        acc, n, t0 = tuple(white), 1, t
    else:
        acc, n, t0 = tuple(a + v for a, v in zip(st.bsum, white, strict=True)), st.bn + 1, st.bt0
    if t - t0 < MEAN_BLOCK_S:
        kw.update(bsum=acc, bn=n, bt0=t0)
        return None
    kw.update(bsum=(), bn=0, bt0=math.nan, blen=n, bk=st.bk + 1)
    root = math.sqrt(n)
    return tuple(a / root for a in acc), t0


def advance(
    st: _Live, t: float, ok: bool, nis: float, gate: float, d: int, opts, white=None, rate=False
) -> _Live:
    """The streaming checks after one gated reading (the Localizer's live health and the
    offline run's findings both come from here: docs/filters.md, "Live health").

    * the test ratio ``nis / gate`` (PX4 EKF2's: above 1 the reading was rejected);
    * windows of ``nis_window`` accepted readings: the window's mean NIS against its
      chi-square band (:func:`window_band`); ``health_persist`` consecutive windows above it
      make the stream failing, ``health_recover`` consecutive windows inside it clear that
      (ArduPilot EKF3's persistence and hysteresis); below the band is a note;
    * rejection runs: ``reject_run`` consecutive rejections make the stream failing too;
    * the innovation-mean scan (:func:`_scan`) of a stream given its whitened innovations
      ``white`` (every stream's), a ``rate`` stream's in blocks
      (:func:`_rate_block`);
    * the rejection count (:func:`_count`) of the last ``nis_window`` readings;
    * reading times, for the outage check.
    """
    w, persist = max(int(opts.nis_window), 1), int(opts.health_persist)
    kw = {"n": st.n + 1, "t_last": t, "ratio": nis / gate if math.isfinite(gate) else 0.0}
    stride = w // 4 or 1  # mean_stride(w), inline (0.2 us a reading): scan and count
    _count(st, kw, t, ok, gate, d, w, stride, opts)
    if st.n == 0:
        kw["t_first"] = t
    elif t - st.t_last > st.gap:
        kw["gap"], kw["gap_t0"] = t - st.t_last, st.t_last
    if not ok:
        run = st.run + 1
        kw["run"] = run
        if run == 1:
            kw["run_t0"] = t
        k = max(int(opts.reject_run), 1)
        if run >= k:
            kw["run_total"] = st.run_total + (k if run == k else 1)
            if run == k:
                kw["runs"] = st.runs + 1
                kw["failing"], kw["good"] = True, 0
            if run > st.longest:
                kw["longest"], kw["long_t0"], kw["long_t1"] = run, kw.get("run_t0", st.run_t0), t
        return st._replace(**kw)
    kw["run"] = 0
    if white is not None and not rate:
        _scan(st, kw, t, white, w, d, stride, opts)
    elif white is not None:
        block = _rate_block(st, kw, t, white, d)
        if block is not None:
            _scan(st, kw, t, block[0], w, d, stride, opts, n=st.bk + 1, t0=block[1])
    kw["tsum"], kw["tn"] = st.tsum + min(nis, 1e12), st.tn + 1
    wsum, wn = st.wsum + min(nis, 1e12), st.wn + 1
    if wn == 1:
        kw["wt0"] = t
    if wn < w:
        kw["wsum"], kw["wn"] = wsum, wn
        return st._replace(**kw)
    k = st.k + 1
    mean = wsum / w
    lo, hi, _ = window_band(k, w, d, opts.nis_alpha, persist)
    t0 = kw.get("wt0", st.wt0)
    kw.update(wsum=0.0, wn=0, k=k, wratio=mean / hi)
    failing, good = kw.get("failing", st.failing), st.good
    if mean > hi:
        bad = st.bad + 1
        bad_t0 = t0 if bad == 1 else st.bad_t0
        worst = max(mean, st.bad_worst if bad > 1 else 0.0)
        kw.update(bad=bad, bad_t0=bad_t0, bad_worst=worst, low=0)
        good = 0
        if bad >= persist:
            if bad == persist:
                kw["episodes"] = st.episodes + 1
                if st.episodes == 0:
                    kw["ep_t0"] = bad_t0
            failing = True
            kw["ep_t1"], kw["ep_worst"] = t, max(st.ep_worst, worst)
    else:
        kw["bad"] = 0
        if failing:
            good += 1
            if good >= int(opts.health_recover):
                failing, good = False, 0
        low = st.low + 1 if mean < lo else 0
        kw["low"] = low
        if low >= persist:
            if low == persist:
                kw["low_episodes"] = st.low_episodes + 1
                if st.low_episodes == 0:
                    kw["low_t0"] = t0
            kw["low_t1"], kw["low_worst"] = t, min(st.low_worst, mean)
    kw["failing"], kw["good"] = failing, good
    return st._replace(**kw)


#: The run's NIS test (:func:`live_findings`) from this many windows' worth of accepted
#: readings of a stream: the mean NIS of all of them against the chi-square bound of their
#: count at ``nis_alpha`` (Bar-Shalom's time-averaged NIS). It sees what the windows with
#: persistence miss: a moderate offset that lasts a minute or two (GPS fixes 8 m off for 15 s
#: pulled an EKF 3 m off for 40 s, NEES 65 while every window was inside its band).
RUN_NIS_MIN_WINDOWS = 2


def live_findings(
    s: str, st: _Live, t0: float, t1: float, opts, d: int, outage: bool = True, gate=math.inf
) -> list[Finding]:
    """The findings of one stream's streaming checks over the run ``[t0, t1]`` (s) (the
    outage check only with ``outage``; ``gate``: the stream's NIS threshold)."""
    out: list[Finding] = []
    w, persist = max(int(opts.nis_window), 1), int(opts.health_persist)
    if st.episodes:
        _, hi, a = window_band(st.k, w, d, opts.nis_alpha, persist)
        now = "; failing now" if st.failing and st.bad >= persist else ""
        out.append(
            Finding(
                "nis",
                f"mean NIS over {w} readings above its band (expected {d}, bound {_s(hi)} at "
                f"{_s(a)} per window) for >= {persist} consecutive windows, {st.episodes} "
                f"time(s); worst {_s(st.ep_worst)}{now}: the filter is overconfident or off"
                f"{nis_keys(s)}",
                sensor=s,
                t_start=st.ep_t0,
                t_end=st.ep_t1,
                figure=st.ep_worst,
            )
        )
    mean = st.tsum / st.tn if st.tn else 0.0
    # P(chi2_k <= k) < 0.6827 for every k, so at nis_alpha <= 0.3 the bound exceeds the
    # expected d: a mean at or below d passes without the quantile (5 us a health() call)
    if st.tn >= RUN_NIS_MIN_WINDOWS * w and (mean > d or opts.nis_alpha > 0.3):
        from odofuse import chi2

        hi = float(chi2.ppf(1.0 - float(opts.nis_alpha), st.tn * d)) / st.tn
        if mean > hi:
            out.append(
                Finding(
                    "nis_run",
                    f"mean NIS of all {st.tn} accepted readings {_s(mean)} above its band "
                    f"(expected {d}, bound {_s(hi)} at {_s(opts.nis_alpha)}): over the run "
                    f"the filter was overconfident or off{nis_keys(s)}",
                    sensor=s,
                    t_start=st.t_first,
                    figure=mean,
                )
            )
    if st.mhits:
        _, a = mean_bound(st.mk, d, opts.nis_alpha)
        blocks = f" blocks of >= {MEAN_BLOCK_S:g} s of" if st.bk else ""
        unit = "blocks" if st.bk else "readings"
        now = "; failing now" if st.mfailing else ""
        out.append(
            Finding(
                "innovation_mean",
                f"mean of {w}{blocks} whitened innovations off zero {st.mhits} time(s): "
                f"|sum|^2 / {w} up to {_s(st.mworst)} x its chi-square({d}) bound (at <= "
                f"{_s(a)} an evaluation, every {mean_stride(w)} {unit}){now}: a bias the "
                f"filter does not model (its NIS can look right){nis_keys(s)}",
                sensor=s,
                t_start=st.m_t0,
                t_end=st.m_t1,
                figure=st.mworst,
            )
        )
    if st.rhits:
        now = "; failing now" if st.rfailing else ""
        p = count_probability(float(gate), d, opts.gross_fraction)
        out.append(
            Finding(
                "rejection_count",
                f"{st.rworst} of {w} consecutive readings rejected by the gate (a consistent "
                f"filter rejects {_s(p)} of them, gross readings included; {st.rbound} or "
                "more at <= "
                f"{_s(count_bound(st.rk, w, p, opts.nis_alpha)[1])} an evaluation), "
                f"{st.rhits} time(s){now}: the estimate and this sensor disagree"
                f"{nis_keys(s)}",
                sensor=s,
                t_start=st.r_t0,
                t_end=st.r_t1,
                figure=float(st.rworst),
            )
        )
    if st.low_episodes:
        out.append(
            Finding(
                "nis",
                f"mean NIS over {w} readings below its band (expected {d}) for >= {persist} "
                f"consecutive windows, {st.low_episodes} time(s); lowest {_s(st.low_worst)}: "
                f"the filter is pessimistic (covariance larger than the errors){nis_keys(s)}",
                sensor=s,
                t_start=st.low_t0,
                t_end=st.low_t1,
                figure=st.low_worst,
                degrades=False,
            )
        )
    if st.runs:
        k = max(int(opts.reject_run), 1)
        out.append(
            Finding(
                "rejection_run",
                f"{st.runs} run(s) of >= {k} consecutive rejections ({st.run_total} readings); "
                f"longest {st.longest} readings over {st.long_t1 - st.long_t0:.2f} s",
                sensor=s,
                t_start=st.long_t0,
                t_end=st.long_t1,
                figure=float(st.longest),
            )
        )
    if outage:
        out += _outage(s, st, t0, t1, opts.reject_run)
    return out


def _outage(s: str, st: _Live, t0: float, t1: float, reject_run: int) -> list[Finding]:
    """:func:`outage_findings` from the streaming record (first, last, longest gap)."""
    if st.n < 2 or not st.t_last > st.t_first:
        return []  # fewer than two readings: no rate to miss (live start-up)
    if not max(st.t_first - t0, st.gap, t1 - st.t_last) > 0.5 * (t1 - t0):
        return []  # the longest gap is within half of the run (every health() call asks)
    gaps = [(st.t_first - t0, t0, st.t_first), (st.gap, st.gap_t0, st.gap_t0 + st.gap)]
    gaps.append((t1 - st.t_last, st.t_last, t1))
    g, a, b = max(gaps, key=lambda x: x[0])
    others = st.t_last - st.t_first - st.gap  # the typical step: without the longest gap
    step = others / (st.n - 2) if st.n > 2 and others > 0 else st.gap
    if not (g > 0.5 * (t1 - t0) and g > max(int(reject_run), 1) * step):
        return []
    return [
        Finding(
            "outage",
            f"no reading for {g:.1f} s of the run's {t1 - t0:.1f} s ({st.n} readings in all): "
            "over that span the estimate is dead reckoning",
            sensor=s,
            t_start=float(a),
            t_end=float(b),
            figure=float(g),
        )
    ]


@functools.lru_cache(maxsize=64)
def _normal_quantile(p: float) -> float:
    """The standard normal ``p``-quantile (a few options' values: cached for the live health)."""
    return NormalDist().inv_cdf(p)


def _largest_eigenvalue(S: np.ndarray) -> float:
    """The largest eigenvalue of the symmetric part of ``S`` (d, d); closed form for d <= 2
    (the live health asks it of every stream each pass)."""
    if S.shape == (1, 1):
        return float(S[0, 0])
    if S.shape == (2, 2):
        (a, b), (c, d) = S.tolist()
        m, h = 0.5 * (a + d), 0.5 * (b + c)
        return m + math.hypot(0.5 * (a - d), h)
    return float(np.linalg.eigvalsh(0.5 * (S + S.T))[-1])


def gate_mde(gate: float, s_max: float, power: float) -> float:
    """Smallest error of one reading that its gate rejects with probability >= ``power``.

    ``(sqrt(gate) + z_power) * sqrt(s_max)``, ``s_max`` the largest eigenvalue of the
    innovation covariance ``S``: an error ``b`` along the worst direction has noncentrality
    ``|b|^2 / s_max``, and the NIS is at least the squared innovation along ``b`` (in ``S``'s
    metric), so the gate fires when that normal draw exceeds ``sqrt(gate)``.
    """
    if not (math.isfinite(gate) and s_max > 0.0):
        return math.inf
    return (math.sqrt(gate) + _normal_quantile(power)) * math.sqrt(s_max)


def window_mde(k: int, w: int, d: int, s_max: float, opts) -> float:
    """Smallest constant error of a stream's readings that its NIS window check detects.

    The error must hold over ``health_persist`` windows, each failing with probability
    ``mde_power^(1 / health_persist)``; a window's summed NIS is then noncentral chi-square
    (``w d`` degrees of freedom, noncentrality ``lambda = w |b|^2 / s_max`` in the worst
    direction), taken normal (mean ``w d + lambda``, variance ``2 (w d + 2 lambda)``): its
    ``1 - power`` quantile reaches the bound ``w hi`` at
    ``lambda = (s^2 - w d) / 2``, ``s = z sqrt(2) + sqrt(2 z^2 + 2 w hi - w d)``.
    """
    if not s_max > 0.0:
        return math.inf
    persist = int(opts.health_persist)
    _, hi, _ = window_band(k + 1, w, d, opts.nis_alpha, persist)
    z = _normal_quantile(float(opts.mde_power) ** (1.0 / persist))
    nu, bound = w * d, w * hi
    root = z * math.sqrt(2.0) + math.sqrt(max(2.0 * z * z + 2.0 * bound - nu, 0.0))
    lam = max(0.5 * (root * root - nu), 0.0)
    return math.sqrt(lam / w * s_max)


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
        #: blocks of :data:`MEAN_BLOCK_S`.
        self.rate_streams = frozenset(
            s for s, m in models.items() if hasattr(m, "clones") and m.clones()
        )
        self._white = {s: array("d") for s in models}
        self._floor = {s: 0 for s in models}  # rejections before this index are handled
        self.live = {s: _Live() for s in models}  # the streaming checks (advance)
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
        the reading's whitened innovation (:func:`whiten`; None: not known, the scan skips
        the reading).
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
        """The streaming checks' findings (:func:`live_findings`) and the recoveries; O(1)
        per stream. ``span`` ``(t0, t1)`` is the run's time span (None: no outage check)."""
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
        return [f for s, st in self.live.items() for f in _outage(s, st, *span, reject_run)]

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


# ----------------------------------------------------------------------------- localizer
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


#: A run of consecutive slipping odometry steps longer than this (s) is a wheel fault, not a
#: slip (chosen a priori): a tyre that spins on a bump or a kerb slips for a fraction of a
#: second; for a second on end the wheels and the gyro disagree on every step only when a wheel
#: spins free, is dragged, or its encoder is stuck, and the widened wheel noise covers the
#: heading but not what the faulty wheel says of the distance (a stuck encoder for 10 s left
#: an EKF 3 m off at NEES 85, ``benchmarks/bench_status.py``). Each step's test has a false
#: alarm of ``1 - slip_gate`` (1e-3): 50 in a row at 50 Hz is beyond any nominal log.
SLIP_RUN_S = 1.0


def slip_note(loc) -> list:
    """A note of the odometry steps on which robust odometry widened the wheel noise, and a
    finding (degrading) when they ran on for more than :data:`SLIP_RUN_S`."""
    if not loc.slip_steps:
        return []
    out = [
        Finding(
            "slip",
            f"gyro and wheels disagreed on {loc.slip_steps} odometry step(s): the "
            "wheel noise of those steps was widened to cover it (robust odometry)",
            sensor=loc._slip_stream,
            figure=float(loc.slip_steps),
            degrades=False,
        )
    ]
    return out + slip_run_findings(loc._slip_stream, *loc._slip_longest, "odometry step")


def slip_run_findings(stream, a: float, b: float, unit: str) -> list:
    """The ``slip_run`` finding of a run of slipping ``unit``s from ``a`` to ``b`` (s) when it
    lasted more than :data:`SLIP_RUN_S` (the filters' steps, the graph's keyframe
    intervals)."""
    if not b - a > SLIP_RUN_S:
        return []
    return [
        Finding(
            "slip_run",
            f"gyro and wheels disagreed on every {unit} for {b - a:.2f} s (more than "
            f"{SLIP_RUN_S:g} s): a wheel spinning free or dragged, or a stuck encoder; the "
            "widened wheel noise covers the heading, not the distance that wheel reports",
            sensor=stream,
            t_start=a,
            t_end=b,
            figure=b - a,
        )
    ]


def mean_mde(j: int, w: int, d: int, s_max: float, opts) -> float:
    """Smallest constant error of ``w`` readings that the innovation-mean scan's ``j``-th
    evaluation detects with probability ``mde_power``: ``(sqrt(bound) + z_power) *
    sqrt(s_max / w)`` (:func:`gate_mde`'s argument for a window's whitened sum, whose mean
    along the error is ``sqrt(w) |b| / sqrt(s_max)`` in the worst direction)."""
    if not s_max > 0.0:
        return math.inf
    bound, _ = mean_bound(j, d, opts.nis_alpha)
    z = _normal_quantile(float(opts.mde_power))
    return (math.sqrt(bound) + z) * math.sqrt(s_max / w)


def heading_increment_var(loc, dt: float) -> float:
    """Variance (rad^2) of the wheels' heading change over ``dt`` s at the last odometry
    step's rate: ``dt / span`` steps of that step's input ``u``, each adding the motion
    model's ``(F_u Sigma_u F_u^T)_theta`` (0 before the first step)."""
    if loc._last_step is None:
        return 0.0
    u, span = loc._last_step
    if not (span > 0.0 and dt > 0.0):
        return 0.0
    _, P, _, _ = loc.motion_model.predict(np.zeros(3), np.zeros((3, 3)), u)
    return float(P[2, 2]) * dt / span


def mde_of(loc) -> dict:
    """Sensor -> ``{"gate", "nis_window", "innovation_mean"}``: the smallest error of a
    reading each check of the stream detects with probability ``mde_power`` (in the sensor's
    units), at the innovation covariance of the stream's last reading under the current
    state covariance (:func:`gate_mde`, :func:`window_mde`, :func:`mean_mde`); None where no
    reading was seen.

    A stream measured against a heading clone (a gyro: ``theta - theta_ref`` over the
    reading's ``dt``) finds its clone just reset, so the covariance now says nothing of the
    wheels' heading noise its next reading meets: that is added at the last odometry step's
    rate (:func:`heading_increment_var`). Without it a 0.01 rad/s gyro on wheels of ``k``
    2e-5 m reported a sixth of its innovations' sigma (docs/trust.md, "The gyro in the
    innovation-mean scan").
    """
    mon, opts = loc.monitor, loc.options
    mon.catch_up()
    x, Pfull = loc.backend.mean(), loc.backend.cov()
    out = {}
    for s, row in loc._last_row.items():
        model = loc.models[s]
        try:
            H = np.atleast_2d(np.asarray(model.H(x, row), dtype=float))
            S = H @ Pfull @ H.T + np.atleast_2d(model.R(row))
            if s in mon.rate_streams and "dt" in row:
                S = S + np.outer(H[:, 2], H[:, 2]) * heading_increment_var(loc, row["dt"])
            s_max = _largest_eigenvalue(S)
        except (KeyError, ValueError, np.linalg.LinAlgError):
            continue  # a row the model cannot read at this state: no figure
        if not math.isfinite(s_max):
            continue
        gate = gate_mde(mon.gates[s], s_max, float(opts.mde_power))
        w = max(int(opts.nis_window), 1)
        window = window_mde(mon.live[s].k, w, mon.dims[s], s_max, opts)
        out[s] = {
            "gate": gate if math.isfinite(gate) else None,
            "nis_window": window if math.isfinite(window) else None,
        }
        mean = mean_mde(mon.live[s].mk + 1, w, mon.dims[s], s_max, opts)
        if s in mon.rate_streams:  # a block sums blen readings (_rate_block)
            mean /= math.sqrt(max(mon.live[s].blen, 1))
        out[s]["innovation_mean"] = mean if math.isfinite(mean) else None
    return out


def inert_findings(loc, mde: dict) -> list:
    """A note per stream whose gate can never fire: no gate, or a smallest detectable error
    larger than the whole span its readings covered (max - min of each component)."""
    out = []
    for s, m in mde.items():
        span = loc._z_span.get(s)
        width = float(np.max(span[1] - span[0])) if span is not None else math.nan
        gate = m["gate"]
        if gate is not None and not (math.isfinite(width) and gate > width > 0.0):
            continue
        what = (
            "it has no gate"
            if gate is None
            else f"its smallest detectable error {_s(gate)} exceeds the span {_s(width)} "
            "of all its readings"
        )
        out.append(
            Finding(
                "inert",
                f"the gate can never fire: {what}; a fault of this sensor goes unseen",
                sensor=s,
                figure=gate,
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


def step_slip_scale(loc, t0: float, t1: float, u) -> float:
    """Input-noise factor of one odometry step (robust odometry, :func:`slip_scale`).

    A backend on the compiled kernels computes it in its kernel (``slip_step``, None where
    it cannot: the offline run's arithmetic, so a live EKF or UKF equals ``odofuse run`` bit
    for bit); this is the reference it equals to 1e-9."""
    g = loc._gyro_increment(t0, t1)
    if g is None or t1 <= t0:
        return 1.0
    span = t1 - t0
    runs = loc._slip_runs
    run = runs.get(t0, 0.0)
    gate, sigma, var_b = loc._slip_params
    kernel = getattr(loc.backend, "slip_step", None)
    out = None
    if kernel is not None:
        learn = np.full(3, np.nan)
        out = kernel(u, span, g, run, loc._slip_params, loc._bias_idx, learn)
    if out is not None:
        scale, after = out
        if loc._bias_idx is not None:
            record_learning_terms(loc._bias_record, t0, *learn.tolist())
    else:
        delta, J = loc._increment(u)
        mm = loc.motion_model
        var_odo = float((J[2] ** 2) @ mm.errors.variances(mm.drive, u, span))
        bias = 0.0
        if loc._bias_idx is not None:
            bias = float(loc.backend.mean()[loc._bias_idx])
            cov = loc.backend.cov()
            var_b = float(cov[loc._bias_idx, loc._bias_idx])
            record_learning(loc._bias_record, t0, cov, loc._bias_idx)
        var_ref = (sigma**2 + var_b) * span**2
        d = g - bias * span - float(delta[2])
        scale = slip_scale(d, var_odo, var_ref, gate, run)
        after = run + d if scale > 1.0 else 0.0
    starts = loc._slip_starts
    if scale > 1.0:
        loc.slip_steps += 1
        begin = starts.get(t0, t0)
        starts[t1] = begin
        longest = loc._slip_longest
        if t1 - begin > longest[1] - longest[0]:
            loc._slip_longest = (begin, t1)
    runs[t1] = after
    if len(runs) > 4096:  # keep what a replay inside the late window can still ask for
        horizon = t1 - loc.late_window - 1.0
        for key in [k for k in runs if k < horizon]:
            del runs[key]
        for key in [k for k in starts if k < horizon]:
            del starts[key]
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
