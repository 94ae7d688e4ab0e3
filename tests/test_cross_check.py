"""The batch smoother's second opinion (odofuse.status.cross_check): its arithmetic on hand-made
trajectories, when it applies, and how it reaches metrics.json through odofuse.rundir."""

import json
import math

import numpy as np
import pytest

from odofuse.config import config_from_dict
from odofuse.io.log import SensorLog, Stream
from odofuse.rundir import checked_metrics, run_one
from odofuse.status import cross_check as xc
from odofuse.trajectory import EstimateResult, Trajectory

SIGMA = 0.01  # m, the hand-made smoother's per-axis position sigma: s = sqrt(2) * SIGMA


def _line(n=201, dy=0.0, var=SIGMA**2):
    """A straight 20 m run at 10 Hz, shifted ``dy`` m sideways, covariance diag(var, var, 1e-4)."""
    t = np.linspace(0.0, 20.0, n)
    poses = np.column_stack([t, np.full(n, dy), np.zeros(n)])
    return Trajectory(t, poses, np.tile(np.diag([var, var, 1e-4]), (n, 1, 1)))


def _smoother():
    t = np.arange(0.0, 20.01, 1.0)  # keyframes: 1 s apart, interpolated to the estimate's times
    traj = _line(t.size)
    return Trajectory(t, np.column_stack([t, np.zeros(t.size), np.zeros(t.size)]), traj.covariances)


def _checks(found):
    return [f.check for f in found]


def test_a_fused_estimate_3_sigma_from_the_smoother_gets_advice_not_a_finding():
    # Issue 25: less accurate than the smoother is advice; its covariance (1 m) covers it.
    s = math.sqrt(2) * SIGMA
    block, found, advice = xc.compare(_line(dy=3 * s, var=1.0), _smoother(), fused=True)
    assert block["departure_rms_m"] == pytest.approx(3 * s)
    assert block["smoother_sigma_m"] == pytest.approx(s)
    assert block["predicted_ratio"] == pytest.approx(math.sqrt(10.0))  # sqrt(1 + 3^2)
    # against the estimate's covariance plus the smoother's
    assert block["departure_nees"] == pytest.approx((3 * s) ** 2 / (1.0 + SIGMA**2))
    assert found == []
    assert len(advice) == 1 and "about 3.2x more accurate" in advice[0]
    assert advice[0].endswith("`estimator: smoother`") and "no error samples" in advice[0]


def test_a_fused_estimate_within_the_smoothers_sigma_gets_no_advice():
    s = math.sqrt(2) * SIGMA
    block, found, advice = xc.compare(_line(dy=s, var=1.0), _smoother(), fused=True)
    assert block["predicted_ratio"] == pytest.approx(math.sqrt(2.0))
    assert found == [] and advice == []
    # just above the ratio: sqrt(1 + 1.8^2) = 2.06 > 2: advice, still no finding
    _, found, advice = xc.compare(_line(dy=1.8 * s, var=1.0), _smoother(), True)
    assert found == [] and len(advice) == 1


def test_the_nees_bound_holds_for_any_correlation_of_its_terms():
    # c = 2 (1 + ln(1 / alpha)); fully correlated terms: the mean is one exponential of mean
    # 2, whose tail at c is exp(-c / 2) = alpha / e <= alpha; independent terms: far less.
    assert xc.nees_bound(0.05) == pytest.approx(2 * (1 + math.log(20)))
    rng = np.random.default_rng(3)
    for alpha in (0.05, 0.01):
        c = xc.nees_bound(alpha)
        one = rng.exponential(2.0, 200_000)
        assert np.mean(one > c) <= alpha
        assert np.mean(one > c) == pytest.approx(alpha / math.e, rel=0.1)
        many = rng.exponential(2.0, (20_000, 50)).mean(axis=1)
        assert np.mean(many > c) < alpha / 100
    assert xc.nees_bound(0.0) == math.inf


def test_dead_reckoning_is_held_to_its_covariance_not_to_the_smoothers_accuracy():
    # 0.5 m off: far outside the smoother's sigma, but inside its own 1 m sigma: no finding.
    block, found, advice = xc.compare(_line(dy=0.5, var=1.0), _smoother(), fused=False)
    assert block["predicted_ratio"] > 30 and block["ratio_bound"] is None
    assert found == [] and advice == []  # no advice for an unaided estimate either
    # The same drift claimed with a 0.1 m sigma: 0.25 / (0.01 + 1e-4) = 24.8 > 8.0
    block, found, _ = xc.compare(_line(dy=0.5, var=0.01), _smoother(), fused=False)
    assert block["departure_nees"] == pytest.approx(0.25 / (0.01 + SIGMA**2))
    assert block["nees_bound"] == pytest.approx(xc.nees_bound(xc.ALPHA))
    assert _checks(found) == ["cross_check_nees"] and "overconfident" in found[0].message
    assert found[0].degrades and (found[0].t_start, found[0].t_end) == (0.0, 20.0)
    # a smaller share of alpha_run: a higher bound
    block, found, _ = xc.compare(_line(dy=0.5, var=0.01), _smoother(), False, alpha=1e-12)
    assert block["nees_bound"] > 24.8 and found == []


def test_poses_outside_the_smoothers_span_are_not_compared():
    est = _line()
    late = Trajectory(est.t + 100.0, est.poses, est.covariances)
    block, found, advice = xc.compare(late, _smoother(), fused=True)
    assert "skipped" in block and found == [] and advice == []


def _log(odometry_rows=50, gps=True, loops=False):
    t = np.linspace(0.0, 10.0, odometry_rows)
    streams = {
        "odometry": Stream("odometry", "odometry.csv", t, ("ds", "dtheta"), np.zeros((t.size, 2)))
    }
    if gps:
        tg = np.arange(0.0, 10.0)
        streams["gps"] = Stream("gps", "gps.csv", tg, ("x", "y"), np.zeros((tg.size, 2)))
    if loops:
        streams["loop_closures"] = Stream("loop_closures", "l.csv", t[:1], ("i",), np.zeros((1, 1)))
    return SensorLog("log", streams)


def _config(estimator="ekf", cross=None, gps=True, options=None):
    d = {
        "log": "x",
        "robot": {"drive": "increments"},
        "estimator": estimator,
        "sensors": {"gps": {"sigma": 1.0}} if gps else {},
        "options": dict(options or {}),
    }
    if cross is not None:
        d["options"]["cross_check"] = cross
    return config_from_dict(d, "c.yaml")


def test_when_the_check_applies():
    assert xc.skip_reason(_config(), _log()) is None
    assert "off" in xc.skip_reason(_config(cross={"smoother": "off"}), _log())
    assert "is the batch smoother" in xc.skip_reason(_config("smoother"), _log())
    assert "no absolute sensor" in xc.skip_reason(_config(gps=False), _log(gps=False))
    assert xc.skip_reason(_config(gps=False, cross={"smoother": "on"}), _log(gps=False)) is None
    assert "pose-graph" in xc.skip_reason(_config(), _log(loops=True))
    slam = {"smoother": {"slam": True}}
    assert "SLAM" in xc.skip_reason(_config(options=slam), _log())
    # auto's size bound: a 1 h 50 Hz log (180,000 steps) is checked, a 10 h one
    # (benchmarks/bench_io.py: 1,800,000) is not; the bound is one option
    assert xc.skip_reason(_config(), _log(180_000)) is None
    assert "1800000 odometry steps" in xc.skip_reason(_config(), _log(1_800_000))
    assert "max_odometry_steps" in xc.skip_reason(
        _config(cross={"max_odometry_steps": 49}), _log(50)
    )


#: A sane reference's variance components (global factor 1 at 100 degrees of freedom).
SANE = {"method": "global", "variance_factor": 1.0, "redundancy": 100, "converged": True}


def _reference(status="ok", vc=SANE):
    extra = {"variance_components": vc} if vc is not None else {}
    return xc.Reference(EstimateResult("smoother", _smoother(), extra=extra), status, 1.0, "c.yaml")


def test_a_degraded_smoother_skips_the_check_and_says_so():
    # issue 31: the skip is a finding in warnings; an EKF's own NIS checks see drift, so it
    # does not degrade; dead reckoning's cannot, so it does
    s = math.sqrt(2) * SIGMA
    far = EstimateResult("ekf", _line(dy=10 * s, var=1.0))
    result, block, advice = xc.cross_check(_config(), _log(), far, _reference("degraded"))
    assert block == {
        "skipped": "the batch smoother's own status is degraded",
        "smoother_status": "degraded",
    }
    (f,) = result.findings
    assert f.check == "cross_check_skipped" and not f.degrades and advice == []
    assert "own status is degraded" in f.message
    dr = EstimateResult("dead_reckoning", _line(dy=10 * s, var=1.0))
    cfg = _config("dead_reckoning")
    (f,) = xc.cross_check(cfg, _log(), dr, _reference("degraded"))[0].findings
    assert f.check == "cross_check_skipped" and f.degrades and "nothing vouches" in f.message
    result, block, advice = xc.cross_check(_config(), _log(), far, _reference)  # lazily, ok
    assert block["smoother_status"] == "ok" and "smoother_config" not in block
    assert result.findings == () and len(advice) == 1  # 10 sigma off: advice, not a finding


def test_the_check_reaches_status_warnings_and_advice():
    s = math.sqrt(2) * SIGMA
    far = EstimateResult("ekf", _line(dy=3 * s, var=1.0))
    m = checked_metrics(_config(), _log(), far, 0.1, _reference())
    assert m["status"] == "ok" and m["warnings"] == []  # covariance covers it: advice only
    assert m["advice"] == xc.cross_check(_config(), _log(), far, _reference())[2]
    assert len(m["advice"]) == 1
    assert m["cross_check"]["predicted_ratio"] == pytest.approx(math.sqrt(10.0))
    # 5 sigma off, claimed with the smoother's own sigma: inconsistent, degraded
    tight = EstimateResult("ekf", _line(dy=5 * s, var=SIGMA**2))
    m = checked_metrics(_config(), _log(), tight, 0.1, _reference())
    assert m["status"] == "degraded" and m["warnings"][0].startswith("[cross_check_nees]")
    assert m["alpha"]["alpha_run"] == 0.05 and m["alpha"]["total"] <= 0.05
    assert m["alpha"]["checks"]["cross_check_nees"] == m["cross_check"]["nees_alpha"]
    off = checked_metrics(_config(cross={"smoother": "off"}), _log(), far, 0.1, _reference())
    assert off["status"] == "ok" and off["warnings"] == [] and off["advice"] == []
    assert off["cross_check"] == {"skipped": "off (options.cross_check.smoother)"}
    json.dumps(m)  # metrics.json-ready


def test_a_shared_reference_names_its_config_and_a_smoother_run_reuses_it(tmp_path):
    ref = xc.Reference(EstimateResult("smoother", _smoother()), "ok", 1.0, "other.yaml")
    cfg = _config("smoother")
    m = run_one(cfg, _log(), tmp_path / "s", ref)
    assert m["poses"] == len(_smoother()) and m["runtime_s"] == 1.0  # not run again
    assert m["cross_check"] == {"skipped": "the estimate is the batch smoother"}
    stored = json.loads((tmp_path / "s" / "metrics.json").read_text(encoding="utf-8"))
    assert stored["cross_check"] == m["cross_check"]
    ref = xc.Reference(
        EstimateResult("smoother", _smoother(), extra={"variance_components": SANE}),
        "ok",
        1.0,
        "other.yaml",
    )
    result, block, _ = xc.cross_check(_config(), _log(), EstimateResult("ekf", _line()), ref)
    assert block["smoother_config"] == "other.yaml"


def test_a_smoother_that_raises_skips_the_check_and_the_run_goes_on():
    from odofuse.errors import ConfigError

    def broken():
        raise ConfigError("options.smoother.lag: not a smoother option\nsecond line")

    est = EstimateResult("ekf", _line())
    result, block, _ = xc.cross_check(_config(), _log(), est, broken)
    assert [f.check for f in result.findings] == ["cross_check_skipped"]
    assert block == {
        "skipped": "the batch smoother failed: ConfigError: options.smoother.lag: not a "
        "smoother option"
    }
    m = checked_metrics(_config(), _log(), est, 0.1, broken)
    assert m["status"] == "ok" and m["cross_check"] == block
    assert m["warnings"] == [result.findings[0].line()]  # issue 31: said, not silent


def _brute_p_fail(est, smoother, samples):
    """p_fail by dense per-sample interpolation (np.interp) at every estimate time."""
    t = est.t
    num, den = [], []
    for e in samples:
        ex, ey = np.interp(t, smoother.t, e[:, 0]), np.interp(t, smoother.t, e[:, 1])
        sx = np.interp(t, smoother.t, smoother.poses[:, 0])
        sy = np.interp(t, smoother.t, smoother.poses[:, 1])
        dx, dy = est.poses[:, 0] - sx, est.poses[:, 1] - sy
        num.append(np.mean((dx + ex) ** 2 + (dy + ey) ** 2))
        den.append(np.mean(ex**2 + ey**2))
    return float(np.mean(np.array(num) > xc.HOLD_RMSE_RATIO**2 * np.array(den)))


def test_p_fail_is_the_posterior_fraction_of_samples_whose_realised_ratio_exceeds_the_bound():
    rng = np.random.default_rng(4)
    sm = _smoother()  # 21 keyframes, estimate at 201 times between them
    # errors correlated along the trajectory: a random offset plus a small per-keyframe part
    samples = SIGMA * (rng.standard_normal((300, 1, 2)) + 0.3 * rng.standard_normal((300, 21, 2)))
    est = _line(dy=1.2 * SIGMA, var=1.0)
    p = xc.posterior_fail(est, sm, samples)
    assert 0.0 < p < 1.0  # the realised ratio scatters across the bound
    assert p == _brute_p_fail(est, sm, samples)
    assert xc.posterior_fail(_line(dy=0.0), sm, samples) == 0.0  # d = 0: R = 1
    assert xc.posterior_fail(_line(dy=100 * SIGMA), sm, samples) == 1.0
    # a block size that splits the estimate's times gives the same figure
    assert xc.posterior_fail(est, sm, samples) == pytest.approx(p)


def test_the_finding_follows_p_fail_not_the_predicted_ratio(monkeypatch):
    """Predicted ratio 1.28 (under 2), but the smoother's posterior errors are one common
    offset (two degrees of freedom): |e|^2 is below 0.32 of its mean with probability
    1 - exp(-0.32) = 0.27, there R > 2, so p_fail > ALPHA fires."""
    rng = np.random.default_rng(9)
    s = math.sqrt(2) * SIGMA
    samples = np.repeat(SIGMA * rng.standard_normal((200, 1, 2)), 21, axis=1)
    est = _line(dy=0.8 * s, var=1.0)
    block, found, advice = xc.compare(est, _smoother(), True, None, samples)
    assert block["predicted_ratio"] == pytest.approx(math.sqrt(1 + 0.8**2))
    assert block["p_fail"] == pytest.approx(1 - math.exp(-0.32), abs=4 * 0.032)
    assert block["p_fail"] == _brute_p_fail(est, _smoother(), samples) > xc.ALPHA
    assert block["samples"] == 200 and block["advice_alpha"] == xc.ALPHA
    assert found == [] and len(advice) == 1  # issue 25: advice, never a finding
    assert f"posterior probability {block['p_fail']:.2f}" in advice[0]
    assert "about 1.3x more accurate" in advice[0]
    # the same estimate against a smoother whose errors average out (independent per
    # keyframe, 21 of them; interpolation between keyframes lowers the mean |e|^2 to 2/3):
    # R^2 ~ 1 + 0.64 * 1.5, above 4 only 3 standard deviations out: no finding
    ind = SIGMA * rng.standard_normal((200, 21, 2))
    block, found, advice = xc.compare(est, _smoother(), True, None, ind)
    assert block["p_fail"] <= xc.ALPHA and found == [] and advice == []
    # monkeypatched SAMPLE_BLOCK (several blocks) changes nothing
    monkeypatch.setattr(xc, "SAMPLE_BLOCK", 7)
    assert xc.compare(est, _smoother(), True, None, ind)[0]["p_fail"] == block["p_fail"]


def test_without_samples_the_advice_rests_on_the_predicted_ratio_and_says_so():
    s = math.sqrt(2) * SIGMA
    block, found, advice = xc.compare(_line(dy=3 * s, var=1.0), _smoother(), fused=True)
    assert block["p_fail"] is None and block["samples"] == 0
    assert found == [] and "no error samples" in advice[0]
    bad = np.zeros((10, 5, 2))  # not one per smoother pose: not used
    block, _, advice = xc.compare(_line(dy=3 * s, var=1.0), _smoother(), True, None, bad)
    assert block["p_fail"] is None and "no error samples" in advice[0]
    # dead reckoning: no ratio at all
    block, _, advice = xc.compare(_line(dy=3 * s, var=1.0), _smoother(), False, None, bad)
    assert block["ratio_bound"] is None and block["advice_alpha"] is None and advice == []
