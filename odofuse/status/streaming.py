"""The streaming checks of one sensor stream: O(1) work a reading, the same arithmetic for a
Localizer's live health and for the offline run's findings (docs/filters.md, "Live health").

:func:`advance` takes a stream's :class:`StreamState` through one gated reading: the test ratio
(PX4 EKF2's), windows of ``nis_window`` readings against their chi-square band with persistence
and hysteresis (ArduPilot EKF3's), the innovation-mean scan (a rate stream's in blocks of
:data:`MEAN_BLOCK_S`), the rejection count, rejection runs and the reading times.
:func:`live_findings` turns a state into the findings ``nis``, ``nis_run``,
``innovation_mean``, ``rejection_count``, ``rejection_run`` and ``outage``. Each check spends its
false-alarm probability over a run of any length (:func:`window_band`, :func:`mean_bound`,
:func:`count_bound`). Fed by :class:`odofuse.status.monitors.FilterMonitor`; the graph back
ends' checks (:mod:`odofuse.status.graph_checks`) use the same bounds and the outage check.

Thresholds are chosen a priori from statistics (chi-square quantiles, false-alarm
probabilities, window lengths counted in readings of the sensor concerned), never from
ground truth.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from odofuse.status.findings import Finding
from odofuse.status.pose_checks import _s


def nis_keys(stream: str) -> str:
    """The config keys an innovation-band finding of ``stream`` points at."""
    if stream == "gyro" or stream.startswith("gyro_"):
        # the gyro's innovation covariance holds the wheels' heading noise (motion.k)
        return f"; keys: sensors.{stream}.sigma and motion.k (k_r, k_l)"
    return f"; keys: sensors.{stream}.sigma"


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


class StreamState(NamedTuple):
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
    mlast: int = 0  # the accepted readings (a rate stream's blocks) at the last evaluation
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
    st: StreamState, kw: dict, t: float, ok: bool, gate: float, d: int, w: int, stride: int, opts
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
    _count_evaluate(st, kw, t, rej, gate, d, w, stride, opts)


def _count_evaluate(st: StreamState, kw: dict, t, rej: tuple, gate, d, w, stride, opts):
    """One evaluation of the rejection count (:func:`_count`): ``rej`` the rejected readings
    among the last ``w``, the window's last reading at time ``t``, into ``kw``."""
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


def end_count(st: StreamState, opts, gate: float, d: int) -> StreamState:
    """The rejection count's evaluation at the end of a stream's run, as :func:`end_scan` is
    the scan's: the window of its last ``nis_window`` readings, when the stride
    (:func:`mean_stride`) left it unevaluated (a burst in a log's last readings otherwise
    ends the run between two evaluations). It is the next evaluation of the same spending
    schedule (:func:`count_bound`), so the count's false-alarm bound holds; a second call
    changes nothing."""
    w = max(int(opts.nis_window), 1)
    stride = mean_stride(w)
    # the stride's evaluations so far are (n - w) // stride + 1 (rk counts them): the last
    # reading was one of them, or the end's evaluation is done already
    if st.n < w or (st.n - w) % stride == 0 or st.rk > (st.n - w) // stride + 1:
        return st
    kw: dict = {}
    _count_evaluate(st, kw, st.t_last, st.rtimes, gate, d, w, stride, opts)
    return st._replace(**kw) if kw else st


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
    st: StreamState, kw: dict, t: float, white, w: int, d: int, stride: int, opts, n=None, t0=None
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
    _evaluate(st, kw, t, win, d, opts, n, stride)


def _evaluate(st: StreamState, kw: dict, t: float, win: tuple, d: int, opts, n: int, stride):
    """One evaluation of the innovation-mean scan (:func:`_scan`) over the window ``win`` of
    whitened innovations, the ``n``-th accepted reading (or block) its last, into ``kw``."""
    w = len(win)
    j = st.mk + 1
    sums = [math.fsum(e[1 + i] for e in win) for i in range(d)]
    stat = math.fsum(v * v for v in sums) / w
    bound, _ = mean_bound(j, d, opts.nis_alpha)
    ratio = stat / bound
    kw.update(mk=j, mratio=ratio, mlast=n)
    if ratio > 1.0:
        kw.update(mhits=st.mhits + 1, mfailing=True, mgood=0, m_t1=t)
        kw["mworst"] = max(st.mworst, ratio)
        if st.mhits == 0:
            kw["m_t0"] = win[0][0]
    elif st.mfailing:
        kw["mfailing"], kw["mgood"] = _still_failing(st.mgood, w, stride)


def end_scan(st: StreamState, opts, d: int, rate: bool = False) -> StreamState:
    """The innovation-mean scan's evaluation at the end of a stream's run (the Localizer's
    :meth:`~odofuse.estimators.localizer.Localizer.finish`, an offline graph's last
    keyframe): the window of its last ``nis_window`` accepted readings (a ``rate`` stream's
    blocks), when the stride (:func:`mean_stride`) left it unevaluated. A bias that begins
    late in a log otherwise ends the run in the readings between two evaluations: a gyro bias
    step at 45 s of a 94 s log pulled an EKF 4 m off in its last 20 s, and its GPS scan ended
    at 20.0 against a bound of 24.5, then 35.9 at the last fix, never evaluated (docs/trust.md,
    "The scan's last window"). It is the next evaluation of the same spending schedule
    (:func:`mean_bound`), so the scan's false-alarm bound holds; a second call changes
    nothing."""
    w = max(int(opts.nis_window), 1)
    n = st.bk if rate else st.tn
    if len(st.mwin) < w or st.mlast == n:
        return st
    kw: dict = {}
    _evaluate(st, kw, st.mwin[-1][0], st.mwin, d, opts, n, mean_stride(w))
    return st._replace(**kw)


#: s: a rate stream's whitened innovations (a gyro's:
#: :attr:`~odofuse.status.monitors.FilterMonitor.rate_streams`) enter the innovation-mean scan
#: summed over blocks of at least this time, so that its window of ``nis_window`` blocks spans
#: as long as a 1 Hz sensor's window of ``nis_window`` readings. A gyro's innovation is its rate
#: against the wheels' heading change over one reading's interval, whose noise the wheels
#: dominate (docs/trust.md, "The gyro in the innovation-mean scan"): a window of 20 readings at
#: 20 Hz sees a bias of a sixth of that noise only after 36 windows.
MEAN_BLOCK_S = 1.0


def _rate_block(st: StreamState, kw: dict, t: float, white, d: int):
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
    st: StreamState,
    t: float,
    ok: bool,
    nis: float,
    gate: float,
    d: int,
    opts,
    white=None,
    rate=False,
) -> StreamState:
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

#: The whole-run tests (this run's mean NIS, the batch smoother's global variance factor in
#: :func:`odofuse.status.cross_check.variance_factor_excess`) flag a misfit of the noise
#: model only when it is significant at the test's alpha *and* larger than this share of the
#: variance: their bound is ``max(chi-square quantile, 1 + RUN_TOLERANCE)`` (times the
#: expected value). A config's sigmas are known to a few per cent at best (a datasheet's
#: figure, one or two digits), and a variance 10 % (a sigma 5 %) optimistic moves the NEES
#: by at most as much, well inside its chi-square band; but over 25 minutes of a 100 Hz
#: stream these tests resolve 2-5 %, and the EKF said ``degraded`` on half the 16-lap logs of
#: the real robot's kind with its NEES within bound (docs/trust.md, "Whole-run tests with a
#: tolerance"). The floor changes nothing where the quantile is above it (at alpha 1e-3,
#: ``n`` readings of dimension ``d`` with ``n d`` below about 2,000), and on a log that
#: matches its config it only lowers the false-alarm rate.
RUN_TOLERANCE = 0.1


def run_bound(quantile: float, expected: float = 1.0) -> float:
    """The bound of a whole-run test whose chi-square quantile is ``quantile`` and whose
    expected value on a matching log is ``expected``: the larger of the quantile and
    ``expected * (1 + RUN_TOLERANCE)`` (:data:`RUN_TOLERANCE`)."""
    return max(float(quantile), float(expected) * (1.0 + RUN_TOLERANCE))


def live_findings(
    s: str, st: StreamState, t0: float, t1: float, opts, d: int, outage: bool = True, gate=math.inf
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
    # the bound is never below the floor: a mean at or below it passes without the quantile
    # (5 us a health() call)
    floor = run_bound(0.0, d)
    if st.tn >= RUN_NIS_MIN_WINDOWS * w and mean > floor:
        from odofuse import chi2

        hi = run_bound(chi2.ppf(1.0 - float(opts.nis_alpha), st.tn * d) / st.tn, d)
        if mean > hi:
            out.append(
                Finding(
                    "nis_run",
                    f"mean NIS of all {st.tn} accepted readings {_s(mean)} above its band "
                    f"(expected {d}, bound {_s(hi)} at {_s(opts.nis_alpha)}, never below "
                    f"{_s(floor)}): over the run "
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
        out += outage_from_state(s, st, t0, t1, opts.reject_run)
    return out


def outage_from_state(
    s: str, st: StreamState, t0: float, t1: float, reject_run: int
) -> list[Finding]:
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
