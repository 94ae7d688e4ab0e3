"""The innovation-mean scan (issue 25; docs/trust.md, "The innovation-mean scan"): its
false-alarm rate on white innovations, a bias it sees that the NIS windows miss, its live
hysteresis, and the same finding from the compiled and the Python EKF.

White innovations are drawn from seeded ``numpy.random.default_rng`` streams; the bias test's
size was fixed from the formula (:func:`mean_mde`) before it was run.
"""

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binom, chi2

from odofuse.declarations import EkfOptions
from odofuse.status import monitors, streaming
from odofuse.status.mde import mean_mde

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _feed(opts, white, d=None, dt=1.0, rate=False, end=False):
    """The streaming checks' state after accepted readings with whitened innovations
    ``white`` (n, d), ``dt`` s apart, each NIS ``|white|^2`` (``rate``: a rate stream's);
    ``end``: then the end of the run (:func:`~odofuse.status.streaming.end_scan`)."""
    d = white.shape[1] if d is None else d
    st = streaming.StreamState()
    for k, v in enumerate(white.tolist()):
        nis = math.fsum(x * x for x in v)
        st = streaming.advance(st, k * dt, True, nis, math.inf, d, opts, v, rate)
    return streaming.end_scan(st, opts, d, rate) if end else st


@dataclasses.dataclass(frozen=True)
class _Gps:
    dim: int = 2
    gate: float | None = None


def test_mean_bound_spends_alpha_over_the_evaluations():
    # block b of evaluations 2^b .. 2^(b+1) - 1 shares alpha 6 / (pi^2 (b + 1)^2): the sum
    # over every evaluation is alpha
    alpha = 1e-3
    total = sum(
        2**b * streaming._mean_bound(b, 2, alpha)[1] for b in range(60)
    )  # the tail past 2^60 evaluations is below 1e-19
    assert total == pytest.approx(alpha, rel=2e-2)
    bound, a = streaming.mean_bound(1, 1, alpha)
    assert a == pytest.approx(alpha * 6 / math.pi**2)
    assert bound == pytest.approx(chi2.ppf(1 - a, 1))
    assert streaming.mean_bound(3, 2, alpha)[0] == streaming.mean_bound(2, 2, alpha)[0]
    assert streaming.mean_stride(20) == 5 and streaming.mean_stride(3) == 1


def test_whiten_is_the_lower_cholesky_solve():
    S = np.array([[4.0, 1.2], [1.2, 0.9]])
    y = np.array([1.5, -0.7])
    L = np.linalg.cholesky(S)
    assert streaming.whiten(y, S) == pytest.approx(tuple(np.linalg.solve(L, y)), rel=1e-12)
    assert streaming.whiten([3.0], [[4.0]]) == (1.5,)
    S3 = np.diag([1.0, 4.0, 9.0])
    assert streaming.whiten([1.0, 2.0, 3.0], S3) == pytest.approx((1.0, 1.0, 1.0))
    assert streaming.whiten(y, np.array([[1.0, 2.0], [2.0, 1.0]])) is None  # not PD


@pytest.mark.parametrize("d", [1, 2])
def test_false_alarm_rate_on_white_innovations_is_within_alpha(d):
    # alpha 0.05 a stream (the option's default is 1e-3: too rare to count here); 400
    # streams of 153 readings each (27 evaluations on the stride, the 28th at the end of
    # the run)
    opts = dataclasses.replace(EkfOptions(), nis_alpha=0.05)
    rng = np.random.default_rng(100 + d)
    n, length = 400, 153
    states = [_feed(opts, rng.standard_normal((length, d)), end=True) for _ in range(n)]
    assert {st.mk for st in states} == {28}
    fired = sum(st.mhits > 0 for st in states)
    assert fired <= binom.ppf(0.99, n, opts.nis_alpha), fired


def test_a_rate_streams_blocks_keep_the_false_alarm_rate_within_alpha():
    # a gyro's readings at 20 Hz enter the scan summed over blocks of >= 1 s, each block's
    # sum / sqrt(n) N(0, 1) under the model: 200 white streams of 75 s, alpha 0.05 a stream
    opts = dataclasses.replace(EkfOptions(), nis_alpha=0.05)
    rng = np.random.default_rng(7)
    n, length = 200, 1500
    states = [
        _feed(opts, rng.standard_normal((length, 1)), dt=0.05, rate=True, end=True)
        for _ in range(n)
    ]
    assert {st.blen for st in states} == {21}  # 1 s at 20 Hz, both ends: 21 readings a block
    assert all(st.bk == length // 21 for st in states)
    assert {st.mk for st in states} == {12}  # 71 blocks: 11 on the stride, 1 at the end
    fired = sum(st.mhits > 0 for st in states)
    assert fired <= binom.ppf(0.99, n, opts.nis_alpha), fired


def test_a_rate_streams_small_bias_is_found_in_its_blocks_not_in_windows_of_readings():
    # A gyro's innovation is its rate against the wheels' heading change over 50 ms, whose
    # noise the wheels dominate: a 0.03 rad/s bias step under an innovation sigma of 0.067
    # rad/s (bench_status's noise-1 robot) is 0.45 sigma a reading. From the MDE formula
    # (mean_mde over sqrt(21) readings a block) the blocked scan sees 0.45 sigma within
    # 30 s at the default alpha; windows of 20 single readings need 1.2 sigma.
    opts = EkfOptions()
    j = 1 + (30 - 20) // 5  # an evaluation 30 s into the run
    per_block = mean_mde(j, 20, 1, 1.0, opts) / math.sqrt(21)
    assert per_block < 0.45 < mean_mde(j * 21, 20, 1, 1.0, opts)
    rng = np.random.default_rng(8)
    white = rng.standard_normal((2000, 1))
    white[1200:] += 0.45  # from 60 s on
    blocked = _feed(opts, white, dt=0.05, rate=True)
    assert blocked.mhits > 0 and 40.0 <= blocked.m_t0  # a window (20 s) before the step
    assert _feed(opts, white, dt=0.05).mhits == 0
    assert _feed(opts, white[:1200], dt=0.05, rate=True).mhits == 0  # before the step


def test_the_scan_evaluates_its_last_window_at_the_end_of_the_run():
    # 103 readings of a 2-D stream: the stride evaluates the windows ending at readings 20,
    # 25, ..., 100 (17 evaluations); the last 20 readings carry a bias of b on one axis. The
    # window ending at 100 holds 17 of them (|sum|^2 / 20 = 14.45 b^2), the last window all
    # 20 (20 b^2), and both evaluations are in block 4 (16-31): one bound. With b^2 between
    # bound / 20 and bound / 14.45 only the end of the run's evaluation sees it.
    opts = EkfOptions()
    bound = streaming.mean_bound(17, 2, opts.nis_alpha)[0]
    assert bound == streaming.mean_bound(18, 2, opts.nis_alpha)[0]
    b = math.sqrt(bound / 17.0)
    white = np.zeros((103, 2))
    white[83:, 0] = b
    st = _feed(opts, white)
    assert (st.mk, st.mhits, st.mlast, st.tn) == (17, 0, 100, 103)
    end = streaming.end_scan(st, opts, 2)
    assert (end.mk, end.mhits, end.mlast) == (18, 1, 103)
    assert end.mworst == pytest.approx(20 * b * b / bound) and end.m_t0 == 83.0
    assert streaming.end_scan(end, opts, 2) == end  # once
    # a run whose last reading was evaluated on the stride: nothing to add
    assert streaming.end_scan(_feed(opts, white[:100]), opts, 2) == _feed(opts, white[:100])
    # through the monitor, as Localizer.finish calls it: the finding appears at the end
    mon = monitors.FilterMonitor(opts, {"gps": _Gps()})
    for k, v in enumerate(white.tolist()):
        mon.observe("gps", float(k), True, v[0] ** 2 + v[1] ** 2, tuple(v))

    def scans():  # (zero innovations elsewhere are a "below its band" note, not tested)
        return [f for f in mon.stream_findings((0.0, 102.0)) if f.check == "innovation_mean"]

    assert not scans()
    mon.end()
    assert len(scans()) == 1 and scans()[0].degrades


def test_a_bias_the_nis_windows_miss_is_found_and_clears_a_window_later():
    # A 2-D stream, 300 readings; readings 120-159 carry a bias of 1.3 sigma on one axis
    # (a 1 m offset of a GPS of sigma 0.77 m): each NIS grows by 1.7 on average, within the
    # NIS windows' band, while 20 readings' whitened sum is 26 sigma-units off zero.
    opts = EkfOptions()
    mon = monitors.FilterMonitor(opts, {"gps": _Gps()})
    rng = np.random.default_rng(11)
    white = rng.standard_normal((300, 2))
    white[120:160, 0] += 1.3
    failing_at = {}
    for k, v in enumerate(white.tolist()):
        mon.observe("gps", float(k), True, v[0] ** 2 + v[1] ** 2, tuple(v))
        failing_at[k] = "gps" in mon.failing()
    st = mon.live["gps"]
    assert st.episodes == 0 and st.mhits > 0
    found = {f.check: f for f in mon.stream_findings((0.0, 299.0))}
    assert "nis" not in found and "nis_run" not in found
    f = found["innovation_mean"]
    assert f.degrades and f.sensor == "gps" and f.figure > 1.0
    assert 100.0 <= f.t_start <= 160.0 and 120.0 <= f.t_end <= 180.0
    # live: failing while the biased readings are in the window, clear a window after
    assert any(failing_at[k] for k in range(130, 180))
    assert not any(failing_at[k] for k in range(205, 300))
    assert not any(failing_at[k] for k in range(0, 120))
    # one evaluation this late detects 1.3 sigma with less than mde_power (several
    # evaluations saw the bias here): its minimal detectable error is above it
    mde = mean_mde(st.mk + 1, 20, 2, 1.0, opts)
    assert 1.3 < mde < 2.0


def test_the_mde_is_detected_with_its_power():
    opts = EkfOptions()
    w, d, j = 20, 2, 8
    mde = mean_mde(j, w, d, 1.0, opts)
    bound = streaming.mean_bound(j, d, opts.nis_alpha)[0]
    rng = np.random.default_rng(5)
    sums = rng.standard_normal((100_000, w, d)).sum(axis=1)
    sums[:, 0] += w * mde
    detected = np.mean((sums**2).sum(axis=1) / w > bound)
    assert detected >= opts.mde_power - 0.005, detected


def test_compiled_and_python_ekf_give_the_same_scan():
    # The compiled core's figure eight (GPS sigma 0.3 m at 1 Hz) with the fixes 0.5 m east
    # of the truth over 20-45 s: both paths whiten every accepted fix alike, so the scan's
    # finding and its minimal detectable error agree to 1e-9 (assert_same_run).
    from compiled_checks import SCENARIO, assert_same_run
    from graph_sim import simulated_run

    from odofuse.estimators.assembly import run_with
    from odofuse.estimators.compiled import ekf as compiled_ekf
    from odofuse.estimators.ekf import make_backend
    from odofuse.io.log import Stream

    log, cfg = simulated_run(SCENARIO, 3, "ekf", {"slip": False, "compiled": "on"})
    st = log.streams["gps"]
    v = st.values.copy()
    v[(st.t >= 20.0) & (st.t < 45.0), st.columns.index("x")] += 0.5
    log = dataclasses.replace(
        log, streams={**log.streams, "gps": Stream(st.name, st.source, st.t, st.columns, v)}
    )
    res, ref = compiled_ekf.run(log, cfg), run_with(log, cfg, "ekf", make_backend)
    assert res is not None
    assert_same_run(res, ref)
    assert 0.0 < ref.extra["mde"]["gps"]["innovation_mean"] < 0.5
    assert [f.sensor for f in ref.findings if f.check == "innovation_mean"] == ["gps"]


def test_rejection_count_bound_is_the_binomial_tail():
    p = streaming.reject_probability(chi2.ppf(0.999, 2), 2)
    assert p == pytest.approx(1e-3, rel=1e-9)
    assert streaming.reject_probability(math.inf, 2) == 0.0
    # first evaluation: share 6.08e-4; P(Bin(20, 1e-3) >= 2) = 1.9e-4 fits, >= 1 (0.0198) not
    k, a = streaming.count_bound(1, 20, p, 1e-3)
    assert k == 2 and a == pytest.approx(1e-3 * 6 / math.pi**2)
    assert binom.sf(k - 1, 20, p) <= a < binom.sf(k - 2, 20, p)
    k8, a8 = streaming.count_bound(8, 20, p, 1e-3)
    assert k8 == 3 and binom.sf(k8 - 1, 20, p) <= a8 < binom.sf(k8 - 2, 20, p)
    assert streaming.count_bound(1, 20, 0.0, 1e-3)[0] == 1  # P(>= 1) = 0: one would fire


def test_the_count_null_adds_the_gross_fraction_to_the_gate():
    gate = float(chi2.ppf(0.999, 2))
    assert streaming.count_probability(gate, 2, 0.0) == pytest.approx(1e-3, rel=1e-9)
    # Huber's contaminated model: 3 % gross readings, the rest rejected at 1e-3
    p = streaming.count_probability(gate, 2, 0.03)
    assert p == pytest.approx(1e-3 + 0.999 * 0.03, rel=1e-12)
    assert streaming.count_probability(math.inf, 2, 0.03) == 0.0  # no gate: no rejection
    assert EkfOptions().gross_fraction == 0.03
    # the first evaluation: two gross fixes among 20 (P 0.12 at 3.1 %) no longer fire
    k, a = streaming.count_bound(1, 20, p, 1e-3)
    assert k == 5 and binom.sf(k - 1, 20, p) <= a < binom.sf(k - 2, 20, p)


def test_rejection_count_false_alarm_rate_is_within_alpha():
    # a gate of 0.9 (a reading rejected one time in ten) so that chance counts are common;
    # alpha 0.05 a stream, 400 streams of 153 readings (off the stride of 5: the end of the
    # run evaluates the last window too, streaming.end_count), no gross readings
    opts = dataclasses.replace(EkfOptions(), nis_alpha=0.05, gross_fraction=0.0)
    gate = float(chi2.ppf(0.9, 1))
    rng = np.random.default_rng(21)
    fired = 0
    for _ in range(400):
        st = streaming.StreamState()
        for k, v in enumerate(rng.chisquare(1, 153).tolist()):
            st = streaming.advance(st, float(k), v <= gate, v, gate, 1, opts)
        fired += streaming.end_count(st, opts, gate, 1).rhits > 0
    assert fired <= binom.ppf(0.99, 400, opts.nis_alpha), fired


def _gross_stream_fires(opts, rng, n: int = 153, share: float = 0.03) -> bool:
    """Whether the count fires on one consistent stream of ``n`` readings (gate 0.999, 2-D)
    a share ``share`` of which is gross (always rejected), the end of its run included."""
    gate = float(chi2.ppf(0.999, 2))
    st = streaming.StreamState()
    gross = rng.random(n) < share
    for k, v in enumerate(rng.chisquare(2, n).tolist()):
        nis = 1e3 if gross[k] else v
        st = streaming.advance(st, float(k), nis <= gate, nis, gate, 2, opts)
    return streaming.end_count(st, opts, gate, 2).rhits > 0


def test_gross_readings_at_their_declared_share_stay_within_alpha():
    # 3 % of the readings gross (a real GNSS receiver's few fixes tens of metres off):
    # within alpha at the default gross_fraction; the Gaussian-only null (0) fires on many
    opts = dataclasses.replace(EkfOptions(), nis_alpha=0.05)
    rng = np.random.default_rng(23)
    fired = sum(_gross_stream_fires(opts, rng) for _ in range(400))
    assert fired <= binom.ppf(0.99, 400, opts.nis_alpha), fired
    gaussian = dataclasses.replace(opts, gross_fraction=0.0)
    rng = np.random.default_rng(23)
    assert sum(_gross_stream_fires(gaussian, rng) for _ in range(400)) > 0.5 * 400


def _rejected_at_the_end(opts, gate: float):
    """103 gated readings of a 2-D stream (reading ``i`` at ``i`` s), rejected at 84-87 and
    101-103 (``rejected``), the others at NIS 1; and the rejection count's bound ``k`` at the
    17th and 18th evaluations (one block: one bound)."""
    p = streaming.count_probability(gate, 2, opts.gross_fraction)
    k = streaming.count_bound(17, 20, p, opts.nis_alpha)[0]
    assert k == streaming.count_bound(18, 20, p, opts.nis_alpha)[0] == 7
    rejected = {84, 85, 86, 87, 101, 102, 103}  # never reject_run (5) in a row
    return k, [
        (float(i), i in rejected, 2.0 * gate if i in rejected else 1.0) for i in range(1, 104)
    ]


def test_the_rejection_count_evaluates_its_last_window_at_the_end_of_the_run():
    # The stride evaluates the windows ending at readings 20, 25, ..., 100 (17 evaluations):
    # the window ending at 100 (81-100) holds 4 rejections, below the bound of 7; the last
    # window (84-103) holds all 7, seen only at the end of the run (streaming.end_count)
    opts = EkfOptions()
    gate = float(chi2.ppf(0.999, 2))
    k, readings = _rejected_at_the_end(opts, gate)
    st = streaming.StreamState()
    for t, bad, nis in readings:
        st = streaming.advance(st, t, not bad, nis, gate, 2, opts)
    assert (st.rk, st.rhits, st.n, st.runs) == (17, 0, 103, 0)
    end = streaming.end_count(st, opts, gate, 2)
    assert (end.rk, end.rhits, end.rworst, end.rbound) == (18, 1, k, k)
    assert (end.r_t0, end.r_t1) == (84.0, 103.0)
    assert streaming.end_count(end, opts, gate, 2) == end  # once
    # a run whose last reading was evaluated on the stride, or shorter than a window: nothing
    on_stride, short = streaming.StreamState(), streaming.StreamState()
    for i, (t, bad, nis) in enumerate(readings[:100]):
        on_stride = streaming.advance(on_stride, t, not bad, nis, gate, 2, opts)
        if i < 19:
            short = on_stride
    assert (on_stride.rk, on_stride.n, short.n) == (17, 100, 19)
    for st_ in (on_stride, short):
        assert streaming.end_count(st_, opts, gate, 2) == st_
    # through the monitor, as Localizer.finish calls it: the finding appears at the end
    mon = monitors.FilterMonitor(opts, {"gps": _Gps(gate=0.999)})
    assert mon.gates["gps"] == pytest.approx(gate)
    for t, bad, nis in readings:
        mon.observe("gps", t, not bad, nis)

    def counts():
        return [f for f in mon.stream_findings((1.0, 103.0)) if f.check == "rejection_count"]

    assert not counts()
    mon.end()
    (f,) = counts()
    assert f.degrades and f.figure == k and (f.t_start, f.t_end) == (84.0, 103.0)


def test_the_smoothers_rejection_count_reads_its_last_window_too():
    # the same readings as residuals at a batch optimum (status.graph_checks): the windows
    # on the stride hold at most 4 beyond the gate, the last window 7
    from types import SimpleNamespace

    from odofuse.estimators.graph.innovations import NIS_OPTIONS
    from odofuse.status.graph_checks import rejection_count_findings

    gate = float(chi2.ppf(0.999, 2))
    k, readings = _rejected_at_the_end(NIS_OPTIONS, gate)
    problem = SimpleNamespace(models={"gps": _Gps(gate=0.999)}, gyro=set())
    t = np.array([r[0] for r in readings])
    nis = np.array([r[2] for r in readings])
    (f,) = rejection_count_findings(problem, {"gps": {"t": t, "chi2": nis}})
    assert f.check == "rejection_count" and f.figure == k and (f.t_start, f.t_end) == (84.0, 103.0)
    # the first 100 readings end on the stride: their windows hold at most 4, no finding
    assert not rejection_count_findings(problem, {"gps": {"t": t[:100], "chi2": nis[:100]}})


def test_a_burst_of_rejections_not_in_a_row_is_counted():
    # GPS multipath at 4 sigma: readings 40-54 rejected one in two, never reject_run (5) in
    # a row: the rejection count fires within the burst and clears a window after the
    # window is back inside its bound
    opts = EkfOptions()
    mon = monitors.FilterMonitor(opts, {"gps": _Gps(gate=0.999)})
    gate = mon.gates["gps"]
    rng = np.random.default_rng(12)
    failing_at = {}
    for k in range(120):
        bad = 40 <= k < 55 and k % 2 == 0
        nis = gate * 2 if bad else float(rng.chisquare(2))
        mon.observe("gps", float(k), nis <= gate, nis)
        failing_at[k] = "gps" in mon.failing()
    st = mon.live["gps"]
    assert st.runs == 0 and st.rhits > 0
    (f,) = [f for f in mon.stream_findings((0.0, 119.0)) if f.check == "rejection_count"]
    assert f.degrades and f.figure >= 3 and 20.0 <= f.t_start <= 55.0 <= f.t_end + 10.0
    assert any(failing_at[k] for k in range(45, 60)) and not any(failing_at[k] for k in range(40))
    # 8 rejections in the window of reading 54 fire it (bound 7 with 3 % gross readings);
    # the window of 64 holds 5 (46-54), inside the bound: four evaluations inside (64, 69,
    # 74, 79: a whole window of readings) clear it
    assert [k for k in range(120) if failing_at[k]] == list(range(54, 79))
