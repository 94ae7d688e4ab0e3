"""Live health (issue 25 items 3 and 4): the offline checks, streamed, with persistence and
hysteresis; and the smallest fault each gate and NIS window can see (its MDE)."""

from __future__ import annotations

import dataclasses
import math
from statistics import NormalDist
from types import SimpleNamespace

import numpy as np
import pytest
from test_ekf import sim_config, simulate

from odofuse import chi2
from odofuse.declarations import EkfOptions
from odofuse.estimators import ekf, particle, run_estimator, ukf
from odofuse.estimators.assembly import events
from odofuse.estimators.common import odometry_inputs
from odofuse.estimators.localizer import assemble
from odofuse.io.log import Stream
from odofuse.motion import motion_model_from_config
from odofuse.status import monitors, streaming
from odofuse.status.findings import assess, status_of
from odofuse.status.mde import _largest_eigenvalue, gate_mde, mde_of, window_mde

BACKENDS = {"ekf": ekf, "ukf": ukf, "particle": particle}
GPS_SIGMA = 0.5


def _with_gps(log, truth, seed, offset=None):
    """``log`` plus a GPS stream at 2 Hz (sigma 0.5 m) of the true positions; ``offset``
    ``(t0, t1, dx, dy)`` adds a multipath bias (m) to the fixes inside ``[t0, t1]``."""
    rng = np.random.default_rng(seed + 1000)
    t_odo = log.streams["odometry"].t
    idx = np.arange(4, len(t_odo), 5)
    xy = truth[idx + 1, :2] + rng.normal(0.0, GPS_SIGMA, (idx.size, 2))
    t = t_odo[idx]
    if offset is not None:
        t0, t1, dx, dy = offset
        inside = (t >= t0) & (t <= t1)
        xy[inside] += [dx, dy]
    streams = dict(log.streams)
    streams["gps"] = Stream("gps", "sim", t, ("x", "y"), xy)
    return dataclasses.replace(log, streams=streams)


def _config(estimator, **options):
    cfg = sim_config(estimator=estimator, **options)
    sensors = {**cfg.sensors, "gps": {"sigma": GPS_SIGMA}}
    opts = {"particles": 300, "seed": 5} if estimator == "particle" else {}
    opts.update(options)
    # on top of sim_config's typed options for the estimator (odometry_calibration: false, the
    # simulated odometry being exact), not instead of them
    typed = dataclasses.replace(cfg.options[estimator], **opts)
    return dataclasses.replace(cfg, sensors=sensors, options={**cfg.options, estimator: typed})


def _live(log, cfg, estimator, every_step=None):
    """Stream ``log`` through a live Localizer (memory-flat, as ``from_config`` makes it),
    asking for its health after every odometry step; returns it and the answers."""
    t, U = odometry_inputs(log, motion_model_from_config(cfg))
    make = BACKENDS[estimator].make_backend
    loc = assemble(cfg, estimator, make, float(t[0]), log, keep_trajectory=False)
    answers = []
    for te, kind, stream, i in events(log, t, U, [s for s in cfg.sensors if s in log.streams]):
        if kind == 1:
            loc.add_odometry(te, U[i])
            answers.append(loc.health())
        else:
            loc.add_measurement(stream, log.streams[stream].row(i))
    loc.finish()
    return loc, answers


def _offline_status(log, cfg, estimator):
    return status_of(assess(run_estimator(estimator, log, cfg)))


# --------------------------------------------------------------------------- the state machine
def _feed_windows(mon, means, t0=0.0):
    """Feed ``mon`` (stream ``gps``, dim 2, windows of 20) one window per mean NIS."""
    t = t0
    states = []
    for m in means:
        for _ in range(20):
            t += 1.0
            mon.observe("gps", t, True, float(m))
        states.append(mon.live["gps"])
    return states, t


def test_persistence_and_hysteresis_of_the_nis_windows():
    opts = EkfOptions(recovery=False)  # health_persist 3, health_recover 3
    mon = monitors.FilterMonitor(opts, {"gps": SimpleNamespace(dim=2, gate=0.999)})
    hi = streaming.window_band(1, 20, 2, opts.nis_alpha, 3)[1]
    bad, good = 2.0 * hi, 2.0  # above the band of every window here (it widens with k)
    # Two failing windows in a row do not make the stream failing (persistence 3).
    states, t = _feed_windows(mon, [good, bad, bad, good, bad, good])
    assert not any(s.failing for s in states) and states[-1].episodes == 0
    hi_2 = streaming.window_band(2, 20, 2, opts.nis_alpha, 3)[1]  # the second window's band
    assert states[1].wratio == pytest.approx(bad / hi_2) and states[1].wratio > 1.0
    assert [f for f in mon.stream_findings((0.0, t)) if f.check == "nis"] == []
    # Three do; it stays failing through two passing windows, and recovers on the third.
    states, t = _feed_windows(mon, [bad, bad, bad, good, good, good], t)
    assert [s.failing for s in states] == [False, False, True, True, True, False]
    (f,) = [f for f in mon.stream_findings((0.0, t)) if f.check == "nis"]
    assert (f.check, f.sensor, f.degrades) == ("nis", "gps", True)
    assert f.t_start == 121.0 and f.t_end == 180.0  # the three failing windows
    # A failing window during recovery starts the count of passing windows again.
    states, t = _feed_windows(mon, [bad, bad, bad, good, good, bad, good, good, good], t)
    assert [s.failing for s in states] == [False] * 2 + [True] * 6 + [False]
    assert states[-1].episodes == 2


def test_the_run_nis_test_sees_a_moderate_offset_the_windows_miss():
    """The mean NIS of all accepted readings against chi2(n d) / n at ``nis_alpha``: 400
    readings each at NIS 2.5 (expected 2: a GPS offset of 0.7 sigma throughout) fail no
    window (band ~3 and wider) but fail the run's test; at NIS 2 they fail neither."""
    opts = EkfOptions(recovery=False)
    bound = chi2.ppf(1.0 - opts.nis_alpha, 800) / 400
    assert 2.0 < bound < 2.5
    for value, fires in ((2.0, False), (2.5, True)):
        mon = monitors.FilterMonitor(opts, {"gps": SimpleNamespace(dim=2, gate=0.999)})
        for k in range(400):
            mon.observe("gps", float(k), True, value)
        found = {f.check: f for f in mon.stream_findings((0.0, 400.0))}
        assert "nis" not in found and ("nis_run" in found) is fires
        if fires:
            f = found["nis_run"]
            assert (f.sensor, f.degrades, f.t_start, f.t_end) == ("gps", True, 0.0, None)
            assert f.figure == pytest.approx(2.5) and f"bound {bound:.3g}" in f.message
    # fewer readings than two windows: no run test yet
    mon = monitors.FilterMonitor(opts, {"gps": SimpleNamespace(dim=2, gate=0.999)})
    for k in range(39):
        mon.observe("gps", float(k), True, 10.0)
    assert "nis_run" not in {f.check for f in mon.stream_findings((0.0, 40.0))}


def test_whole_run_tests_flag_no_misfit_below_their_tolerance():
    """On 40,000 readings (25 min of a 25 Hz gyro) the run's NIS quantile is 1.02: a noise
    model 5 % optimistic would be significant, but it is inside ``RUN_TOLERANCE`` (10 % of
    the variance), so neither the run's NIS test nor the smoother's variance factor flags
    it; 15 % is flagged by both. Where the quantile is above the floor (the 400 GPS fixes of
    the test above) the floor changes nothing."""
    from odofuse.status.cross_check import variance_factor_excess

    opts = EkfOptions(recovery=False)
    n = 40_000
    assert chi2.ppf(1.0 - opts.nis_alpha, n) / n < 1.0 + streaming.RUN_TOLERANCE / 4
    assert streaming.RUN_TOLERANCE == 0.1
    for value, fires in ((1.05, False), (1.15, True)):
        mon = monitors.FilterMonitor(opts, {"gyro": SimpleNamespace(dim=1, gate=0.999)})
        for k in range(n):
            mon.observe("gyro", 0.04 * k, True, value)
        found = {f.check: f for f in mon.stream_findings((0.0, 0.04 * n))}
        assert ("nis_run" in found) is fires
        if fires:
            assert "bound 1.1 at 0.001" in found["nis_run"].message
        vc = {"variance_factor": value, "redundancy": n}
        assert (variance_factor_excess(vc, 1e-3) is not None) is fires
    assert streaming.run_bound(2.33, 2) == 2.33 and streaming.run_bound(1.02) == 1.1


def test_a_rejection_run_makes_the_stream_failing_until_its_windows_pass():
    opts = EkfOptions(recovery=False)
    mon = monitors.FilterMonitor(opts, {"gps": SimpleNamespace(dim=2, gate=0.999)})
    gate = mon.gates["gps"]
    for k in range(5):
        mon.observe("gps", float(k), False, 2.0 * gate)
    st = mon.live["gps"]
    assert st.failing and st.runs == 1 and st.ratio == pytest.approx(2.0)
    _feed_windows(mon, [2.0, 2.0], 10.0)
    assert mon.failing() == ["gps"]
    _feed_windows(mon, [2.0], 100.0)
    assert mon.failing() == []
    # five rejections in a row are also five in one window of 20 (the rejection count)
    found = [f.check for f in mon.stream_findings((0.0, 200.0))]
    assert found == ["rejection_count", "rejection_run"]


def test_the_band_spends_the_false_alarm_probability_over_a_run_of_any_length():
    alpha, persist = 1e-3, 3
    # Onset probability of window k (persist windows in a row) summed over an endless run.
    total = 0.0
    for b in range(60):
        a = streaming.window_band(2**b, 20, 2, alpha, persist)[2]
        assert streaming.window_band(2 ** (b + 1) - 1, 20, 2, alpha, persist)[2] == a
        total += 2**b * a**persist
    # The blocks' shares 6 / (pi^2 (b + 1)^2) sum to 1: the first 60 blocks to 1 - ~1/60.
    tail = 6.0 / math.pi**2 * sum(1.0 / (b + 1) ** 2 for b in range(60, 10**6))
    assert total == pytest.approx(alpha * (1.0 - tail), rel=1e-5) and total < alpha
    lo, hi, a = streaming.window_band(1, 20, 2, alpha, persist)
    assert hi == pytest.approx(chi2.ppf(1 - a, 40) / 20) and lo == pytest.approx(
        chi2.ppf(a, 40) / 20
    )


def test_nominal_windows_fail_at_the_stated_rate():
    # Consistent NIS (chi-square 2): the per-window false-alarm probability is the band's.
    rng = np.random.default_rng(11)
    opts = EkfOptions(recovery=False)
    mon = monitors.FilterMonitor(opts, {"gps": SimpleNamespace(dim=2, gate=1.0)})
    nis = rng.chisquare(2, 20 * 4000)
    failed = 0
    for j, v in enumerate(nis):
        before = mon.live["gps"].k
        mon.observe("gps", float(j), True, float(v))
        st = mon.live["gps"]
        failed += st.k > before and st.wratio > 1.0
    # Windows 2048..4000 are in block 11; the earlier ones have larger a: bound the count.
    a = [streaming.window_band(k, 20, 2, opts.nis_alpha, 3)[2] for k in range(1, 4001)]
    expected = sum(a)
    assert failed <= expected + 4 * math.sqrt(expected), (failed, expected)
    assert failed >= expected - 4 * math.sqrt(expected), (failed, expected)


# --------------------------------------------------------------------------- live == offline
@pytest.mark.parametrize(
    "estimator",
    # two 120 s logs, live and offline with its second opinion: 1.8-4.4 s since robust
    # odometry runs in the kernels (10-12 s before; 2026-12-04, AMD EPYC)
    ["ekf", "ukf", "particle"],
)
def test_live_status_equals_the_offline_status(estimator):
    for seed, offset in ((31, None), (32, (20.0, 60.0, 2.0, -1.0))):
        log, truth = simulate(seed, steps=1200)  # 120 s: 30 s after the burst to recover
        log = _with_gps(log, truth, seed, offset)
        cfg = _config(estimator)
        loc, answers = _live(log, cfg, estimator)
        h = loc.health()
        offline = _offline_status(log, cfg, estimator)
        assert h.run_status == offline, (seed, [f.line() for f in h.findings])
        assert offline == ("ok" if offset is None else "degraded"), (estimator, seed)
        if offset is None:
            assert all(a.status == "ok" for a in answers)
        else:  # failing during the burst, recovered after it (hysteresis), on record
            during = [a.status for a in answers if 30.0 <= a.t <= 60.0]
            assert "degraded" in during and h.status == "ok"
            assert any(f.degrades and f.sensor == "gps" for f in h.findings)
        assert set(h.test_ratios) == {"ranges", "gps"} and h.t == loc.t


def test_one_unlucky_window_does_not_flip_the_status():
    log, truth = simulate(33, steps=800)
    log = _with_gps(log, truth, 33)
    gps = log.streams["gps"]
    # 20 consecutive fixes (one window's worth) 1.5 sigma off in random directions: within the
    # gate, the window (or the two it straddles) fails its band (mean NIS ~4), and the run's
    # mean NIS stays inside its own (3.3 sigma off, NIS ~11, is a fault the run test sees).
    rng = np.random.default_rng(5)
    xy = gps.values.copy()
    k0 = 40
    ang = rng.uniform(0, 2 * np.pi, 20)
    xy[k0 : k0 + 20] += 1.5 * GPS_SIGMA * np.column_stack([np.cos(ang), np.sin(ang)])
    log = dataclasses.replace(
        log, streams={**log.streams, "gps": Stream("gps", "sim", gps.t, gps.columns, xy)}
    )
    cfg = _config("ekf", compiled="off")
    loc, answers = _live(log, cfg, "ekf")
    ratios = [a.nis_ratios["gps"] for a in answers]
    assert np.nanmax(ratios) > 1.0  # a window did fail
    assert all(a.status == "ok" for a in answers) and loc.health().run_status == "ok"
    assert _offline_status(log, cfg, "ekf") == "ok"


def test_a_range_sensor_reading_5_percent_long_degrades_live_and_offline():
    log, truth = simulate(34, steps=800, scale=1.05)
    log = _with_gps(log, truth, 34)
    cfg = _config("ekf")
    loc, answers = _live(log, cfg, "ekf")
    h = loc.health()
    assert h.status == h.run_status == _offline_status(log, cfg, "ekf") == "degraded"
    assert any(f.sensor == "ranges" and f.degrades for f in h.findings), h.findings
    first = next(a.t for a in answers if a.status == "degraded")
    assert first < 40.0  # within the first windows of ranges (5 Hz, windows of 20)


# --------------------------------------------------------------------------- what a gate can see
def test_gate_mde_is_detected_with_its_power():
    g, S, power = chi2.ppf(0.999, 1), 0.04, 0.95
    mde = gate_mde(g, S, power)
    assert mde == pytest.approx((math.sqrt(g) + NormalDist().inv_cdf(power)) * math.sqrt(S))
    rng = np.random.default_rng(3)
    y = mde + rng.normal(0.0, math.sqrt(S), 200_000)
    assert np.mean(y * y / S > g) >= power - 0.005
    # A 2-D gate: the worst direction's noise; the bound holds there too (it is conservative).
    g2 = chi2.ppf(0.999, 2)
    S2 = np.diag([0.25, 0.04])
    m2 = gate_mde(g2, 0.25, power)
    y = np.array([m2, 0.0]) + rng.normal(0.0, 1.0, (200_000, 2)) * np.sqrt(np.diag(S2))
    assert np.mean(np.einsum("ij,ij->i", y @ np.linalg.inv(S2), y) > g2) >= power
    assert gate_mde(math.inf, S, power) == math.inf


def test_window_mde_is_detected_with_its_power_over_the_persistence():
    opts = EkfOptions()
    w, d, S = 20, 2, 0.3
    mde = window_mde(0, w, d, S, opts)
    rng = np.random.default_rng(4)
    hi = streaming.window_band(1, w, d, opts.nis_alpha, opts.health_persist)[1]
    n = 20_000
    y = mde + rng.normal(0.0, math.sqrt(S), (n, opts.health_persist, w))
    z = rng.normal(0.0, math.sqrt(S), (n, opts.health_persist, w))  # the other axis
    mean = ((y * y + z * z) / S).mean(axis=2)
    detected = np.all(mean > hi, axis=1).mean()
    assert detected >= opts.mde_power - 0.01, detected
    assert window_mde(0, w, d, S / 4, opts) == pytest.approx(mde / 2)


def test_results_report_the_mde_of_every_gate_and_window_in_metrics():
    from odofuse.evaluation import metrics

    log, truth = simulate(35, steps=400)
    log = _with_gps(log, truth, 35)
    py = run_estimator("ekf", log, _config("ekf", compiled="off"))
    compiled = run_estimator("ekf", log, _config("ekf"))
    for s in ("ranges", "gps"):
        m_py, m_c = py.extra["mde"][s], compiled.extra["mde"][s]
        assert m_py["gate"] == pytest.approx(m_c["gate"], rel=1e-6)
        assert m_py["nis_window"] == pytest.approx(m_c["nis_window"], rel=1e-6)
        assert 0.0 < m_py["nis_window"] < m_py["gate"]  # 60 readings see a smaller bias
    # GPS at 0.5 m: a single fix is seen from ~2 m on (sqrt(13.8) + 1.64) * ~0.5.
    assert 1.5 < py.extra["mde"]["gps"]["gate"] < 3.5
    m = metrics(py, log)
    assert m["sensors"]["gps"]["mde"] == py.extra["mde"]["gps"]
    assert not [f for f in assess(py) if f.check == "inert"]


def test_a_gyros_mde_is_at_the_innovation_covariance_its_readings_meet(monkeypatch):
    """A gyro is measured against a heading clone that every reading resets, so the state
    covariance after it says nothing of the wheels' heading noise the next reading meets: the
    MDE must still be at the innovation covariance the readings had (``mde_of`` adds the
    heading noise of the reading's interval; before, it reported the gyro's own 0.005 rad/s
    here, a twelfth of the innovations' sigma)."""
    from gyro_sim import gyro_localizer

    from odofuse.measurements import gate_threshold

    seen = []
    update = ekf.EkfBackend.update

    def record(self, model, row):
        out = update(self, model, row)
        seen.append(float(self.last_innovation[1][0, 0]))
        return out

    monkeypatch.setattr(ekf.EkfBackend, "update", record)
    loc = gyro_localizer(ekf.EkfBackend, 2000, name="ekf")
    mde = mde_of(loc)["gyro"]
    z = NormalDist().inv_cdf(loc.options.mde_power)
    sigma = mde["gate"] / (math.sqrt(gate_threshold(0.999, 1)) + z)
    assert sigma == pytest.approx(math.sqrt(np.median(seen)), rel=0.02)
    assert sigma > 10 * 0.005  # the wheels' heading noise, not the gyro's own
    assert mde["nis_window"] < mde["gate"]


def test_a_gate_that_can_never_fire_is_reported_inert():
    log, truth = simulate(36, steps=400)
    log = _with_gps(log, truth, 36)
    cfg = _config("ekf", compiled="off")
    cfg = dataclasses.replace(cfg, sensors={**cfg.sensors, "gps": {"sigma": 500.0}})
    res = run_estimator("ekf", log, cfg)
    (f,) = [f for f in res.findings if f.check == "inert"]
    assert f.sensor == "gps" and not f.degrades and f.figure > 1000.0
    assert "never fire" in f.line()


def test_the_run_nis_bound_exceeds_its_mean_so_a_mean_below_it_skips_the_quantile():
    """``live_findings`` skips the quantile when the mean NIS is at most ``d``: valid because
    the (1 - alpha) quantile of chi2_k exceeds k for every k at alpha <= 0.3."""
    from odofuse import chi2

    k = np.arange(1, 20001)
    for alpha in (0.3, 0.05, 1e-3, 1e-9):
        assert np.all(np.asarray(chi2.ppf(1.0 - alpha, k)) > k), alpha


def test_an_episode_of_the_kept_poses_outlives_them_in_the_run_status():
    """The checks over the kept poses see only the late window's poses (a live Localizer
    forgets the older ones); an episode they found stays in ``findings`` and ``run_status``
    once its poses are forgotten, as the offline run (every pose kept) reports it."""
    from odofuse.config import RunConfig
    from odofuse.estimators.localizer import HEALTH_TRACK_EVERY, Localizer

    cfg = RunConfig(
        log="live",
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": [1e-3, 1e-4], "var_floor": 1e-8},
        estimator="ekf",
        # a tiny initial sigma: the position sigma grows 10-fold in the first 5 s of odometry
        initial={"pose": [0.0, 0.0, 0.0], "sigma": [1e-3, 1e-3, 1e-3]},
        sensors={"gps": {"sigma": 0.5}},
        options={"ekf": {"growth_factor": 10.0}},
    )
    loc = Localizer.from_config(cfg, 0.0)
    rng = np.random.default_rng(7)
    u, dt = np.array([0.01, 0.001]), 0.02
    x = y = th = 0.0
    first = None
    for k in range(1, 3 * HEALTH_TRACK_EVERY):
        loc.add_odometry(k * dt, u)
        th += u[1]
        x, y = x + u[0] * math.cos(th), y + u[0] * math.sin(th)
        if k > 250 and k % 50 == 0:  # GPS once a second from 5 s on
            ex, ey = rng.normal(0.0, 0.5, 2)
            loc.add_measurement("gps", {"t": k * dt, "x": x + ex, "y": y + ey})
        if k == 250:
            first = loc.health()
    last = loc.health()
    (grew,) = [f for f in first.findings if f.check == "covariance_growth"]
    assert grew.t_end <= 5.0 and first.run_status == "degraded"
    kept_from = float(loc._track.arrays()[0][0])
    assert kept_from > grew.t_end  # its poses are forgotten by now
    assert grew in last.findings and last.run_status == "degraded"
    assert last.status == "ok"  # the episode is over


def test_the_largest_eigenvalue_in_closed_form_equals_lapack():
    rng = np.random.default_rng(3)
    for d in (1, 2, 3):
        for _ in range(200):
            A = rng.normal(size=(d, d))
            S = A @ A.T + 1e-3 * np.eye(d)
            S[0, -1] += 1e-9  # a slightly asymmetric S: its symmetric part's eigenvalue
            want = np.linalg.eigvalsh(0.5 * (S + S.T))[-1]
            assert _largest_eigenvalue(S) == pytest.approx(want, rel=1e-12)
