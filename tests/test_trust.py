"""Issue 10: monitors without ground truth, recovery, a particle filter that does not collapse,
honest scoring, and the scenario set (fast versions) with zero silent failures."""

import dataclasses
import math

import numpy as np
import pytest
from gyro_sim import gyro_localizer

from odofuse.config import config_from_dict
from odofuse.declarations import ParticleOptions
from odofuse.errors import ConfigError, InputError
from odofuse.estimators.particle import ParticleBackend
from odofuse.evaluation import covered, metrics
from odofuse.io.log import SensorLog, Stream
from odofuse.status import monitors
from odofuse.status.slip import slip_scale
from odofuse.teaching import trust_scenarios as ts
from odofuse.trajectory import EstimateResult, Trajectory


def test_inflation_admits_the_innovation_at_its_expected_nis():
    # 1-D: y = 3, A = 0.01, R = 1: lambda solves 9 / (0.01 lambda + 1) = 1 -> lambda = 800.
    lam = monitors.inflation_factor([3.0], [[1.01]], [[1.0]], 1, 1e6)
    assert lam == pytest.approx(800.0, rel=1e-6)
    assert monitors.inflation_factor([0.1], [[1.01]], [[1.0]], 1, 1e6) == 1.0
    assert monitors.inflation_factor([3.0], [[1.0]], [[1.0]], 1, 1e6) == 1e6  # A = 0: cap


def test_slip_scale_widens_only_a_disagreement_the_models_cannot_explain():
    gate = 10.83  # chi2.ppf(0.999, 1)
    assert slip_scale(1e-3, 1e-6, 1e-8, gate) == 1.0
    assert slip_scale(0.01, 1e-6, 1e-8, gate) == pytest.approx(100.0)


def test_a_sensor_silent_for_most_of_the_run_is_an_outage_that_degrades():
    from types import SimpleNamespace

    from odofuse.declarations import EkfOptions

    gps = SimpleNamespace(dim=2, gate=0.999)
    mon = monitors.FilterMonitor(EkfOptions(), {"gps": gps, "ranges": gps})
    for tk in np.r_[np.arange(0.0, 60.0), np.arange(240.0, 282.0)]:
        mon.observe("gps", float(tk), True, 2.0)
    for tk in np.r_[np.arange(0.0, 100.0), np.arange(200.0, 282.0)]:  # 100 s: under half
        mon.observe("ranges", float(tk), True, 2.0)
    t = np.arange(0.0, 282.0, 0.5)
    found = [f for f in mon.findings(t, np.tile(np.eye(3), (t.size, 1, 1)), {}) if f.degrades]
    assert [(f.check, f.sensor, f.t_start, f.t_end) for f in found] == [
        ("outage", "gps", 59.0, 240.0)
    ]
    fresh = monitors.FilterMonitor(EkfOptions(), {"gps": gps})  # live start-up: no rate yet
    fresh.observe("gps", 0.0, True, 2.0)
    assert not fresh.findings(t[:3], np.tile(np.eye(3), (3, 1, 1)), {})


def _learning_record(times, cov_at):
    from array import array

    from odofuse.status import pose_checks

    rec = tuple(array("d") for _ in range(4))
    for tk in times:
        pose_checks.record_learning(rec, float(tk), cov_at(tk), 3)
    return rec


def _heading_bias_cov(var_theta, cov_tb, var_b):
    P = np.eye(4) * 1e-4
    P[2, 2], P[3, 3], P[2, 3], P[3, 2] = var_theta, var_b, cov_tb, cov_tb
    return P


def test_learning_check_fires_when_the_heading_rests_on_a_bias_still_being_learnt():
    from odofuse.status import pose_checks

    # The heading fully explained by the bias (correlation 1) until 70 s, when the bias is
    # learnt (variance 1e-4 -> 1e-6): with the final bias the heading variance would have been
    # 1e-2 of its own, sigma 10x smaller, over 70 % of the run.
    def cov_at(tk):
        vb = 1e-4 if tk < 70.0 else 1e-6
        return _heading_bias_cov(vb * 100.0, vb * 10.0, vb)

    rec = _learning_record(np.arange(0.0, 100.0, 0.02), cov_at)
    assert list(rec[0]) == [0.0, 70.0]  # one entry per change, not one per step
    (f,) = pose_checks.learning_findings("gyro_bias", "gyro", rec, 0.0, 100.0, 1e-6)
    assert (f.check, f.sensor, f.t_start, f.degrades) == ("learning", "gyro", 0.0, False)
    assert f.t_end == pytest.approx(70.0) and f.figure == pytest.approx(0.7)
    assert "up to 10x" in f.line()
    pose_checks.record_learning(rec, 50.0, cov_at(50.0), 3)  # a replay from 50 s
    assert list(rec[0]) == [0.0]  # drops what follows (its value is the last entry's)
    # The same bias learnt late, but the heading pinned by other sensors (bias explains 1 %
    # of its variance): knowing the bias would not change the heading, nothing to report.
    rec = _learning_record(
        np.arange(0.0, 100.0, 0.02),
        lambda tk: _heading_bias_cov(1e-2, 1e-4 if tk < 70 else 1e-5, 1e-4 if tk < 70 else 1e-6),
    )
    assert pose_checks.learning_findings("gyro_bias", "gyro", rec, 0.0, 100.0, 1e-6) == []
    # A constant learnt at a steady rate (heading all bias, P_bb ~ 1 / t): its sigma is above
    # 2x the final one until t = 25 s, a quarter of the run: not "learnt late".
    rec = _learning_record(
        np.arange(1.0, 101.0, 0.02),
        lambda tk: _heading_bias_cov(1e-2 / tk, 1e-3 / tk, 1e-4 / tk),
    )
    assert len(rec[0]) <= math.log(101.0) / 0.01 + 1  # one per 1 % change (of 5000 steps)
    assert pose_checks.learning_findings("gyro_bias", "gyro", rec, 0.0, 100.0, 1e-6) == []


def test_options_are_one_dataclass_with_units_and_errors_name_the_key():
    for f in dataclasses.fields(ParticleOptions):
        assert f.metadata["unit"] and f.metadata["doc"]
    cfg = config_from_dict(
        {"log": "x", "robot": {"drive": "increments"}, "options": {"ekf": {"reject_run": 7}}},
        "c.yaml",
    )
    assert cfg.estimator_options("ekf").reject_run == 7
    with pytest.raises(ConfigError, match="options.ekf.recovery"):
        config_from_dict(
            {"log": "x", "robot": {"drive": "increments"}, "options": {"ekf": {"recovery": 3}}},
            "c.yaml",
        )


def _gt_log(t, poses):
    gt = Stream("groundtruth", "gt.csv", t, ("x", "y", "theta"), poses)
    return SensorLog("log", {}, {}, gt, {})


def _est(t):
    t = np.asarray(t, dtype=float)
    return EstimateResult(
        "ekf", Trajectory(t, np.zeros((t.size, 3)), np.tile(np.eye(3), (t.size, 1, 1)))
    )


def test_ground_truth_gaps_are_not_interpolated_across():
    gt_t = np.r_[np.arange(0.0, 3.0, 0.1), np.arange(7.0, 10.0, 0.1)]
    mask = covered(np.arange(0.0, 10.0, 0.5), gt_t)
    assert mask[:6].all() and not mask[7:14].any() and mask[14:].all()


def test_score_over_part_of_the_estimate_says_so_and_reports_its_coverage():
    t = np.arange(0.0, 100.0, 1.0)
    m = metrics(_est(t), _gt_log(np.arange(0.0, 20.0), np.zeros((20, 3))))
    assert m["groundtruth"]["poses_scored"] == 20 and m["groundtruth"]["covered_s"] == 19.0
    assert m["status"] == "degraded" and m["warnings"][-1].startswith("[scoring]")


def test_non_finite_ground_truth_names_file_and_row():
    poses = np.zeros((5, 3))
    poses[3, 1] = 1e308
    with pytest.raises(InputError, match=r"gt.csv, row 5, column 'y'"):
        metrics(_est(np.arange(5.0)), _gt_log(np.arange(5.0), poses))


def test_figure_eight_filters_recover_within_2x_of_the_smoother():
    log, cfg = ts.figure_eight()
    ref = ts.smoother_reference(log, cfg)  # one smoother run: the yardstick and the cross-check
    smoother = ts.run(log, cfg, "smoother", reference=ref)["ate_rmse_m"]
    for est in ("ekf",):
        m = ts.run(log, cfg, est, reference=ref)
        assert m["ate_rmse_m"] < 0.2, m["ate_rmse_m"]  # 5.62 m before issue 10
        assert ts.judge(m, smoother) != "SILENT"


#: (scenario, estimator) pairs that still fail silently at one lap when the filter runs alone
#: (cross-check off, as in a live pipeline; measured, not hidden: each is a strict xfail, so a
#: fix shows up as an unexpected pass; docs/trust.md has the figures).
#: Since issue 25 item 6 the judge asks for consistency (position NEES below 10) and no
#: divergence (RMSE within 5x the best estimator on the log), not for 2x of the smoother: the
#: filters on slip_bursts (EKF 0.0322 m, 2.66x the smoother's 0.0121 m, NEES 2.39; particle
#: 0.0417 m, 3.4x, NEES 4.0) and gps_outage (EKF 0.308 m, 2.3x, NEES 3.1; particle 0.361 m,
#: 2.7x, NEES 3.1) are consistent and within 5x: they hold (they were silent under the
#: issue-10 judge). The start-up with an unknown gyro bias on GPS alone (1 m sigma), seed 7,
#: gyro_bias_walk: on the status branch (old defaults) EKF 0.263 m, NEES 2.85, particle
#: 0.271 m, NEES 2.68, against the smoother's 0.047 m: 5.6x and 5.8x, both silent. With the
#: issue-25 defaults (gyro bias estimated, odometry_calibration auto: this log's E_d 1.001,
#: E_b 1.005 are now estimated) the EKF holds: 0.214 m, NEES 1.34, 4.2x the smoother's
#: 0.0508 m (its strict xfail passed unexpectedly, so it left this set); with the wheel radius
#: scale calibrated too (issue 25, prior sigma 0.02) 0.2185 m, NEES 1.03, 3.6x the smoother's
#: 0.0613 m. The particle filter (200 particles) was the last one silent there, 0.382 m, NEES
#: 6.5, 6.2x: its calibration states' Liu-West kernel (``roughening`` 0.1) let the cloud settle
#: on seed-dependent values; at the default 0.3 (session 33, chosen without ground truth:
#: benchmarks/bench_particle_seeds.py) it holds, 0.234 m, NEES 1.11, 3.8x the smoother, and its
#: strict xfail passed unexpectedly.
KNOWN_SILENT: set = set()
#: Runs whose second opinion must advise the smoother (the test asserts it): the gyro_bias_walk
#: EKF and particle filter, which hold but stay about 1.9x and 2.1x less accurate than the
#: smoother (posterior probability 0.52 and 0.63 of more than 2x).
SMOOTHER_ADVISED = {("gyro_bias_walk", "ekf"), ("gyro_bias_walk", "particle")}

_TRUST_ESTIMATORS = (("dead_reckoning", None), ("ekf", None), ("particle", {"particles": 200}))
_SCENARIO_CACHE: dict = {}
_ESTIMATE_CACHE: dict = {}


def _scenario_and_smoother(name):
    """``(log, config, smoother metrics, smoother reference)`` of a one-lap scenario, computed
    once per session: the smoother is the judge's yardstick and the cross-check's reference."""
    if name not in _SCENARIO_CACHE:
        log, cfg = ts.simulated(name, laps=1)
        ref = ts.smoother_reference(log, cfg)
        _SCENARIO_CACHE[name] = (log, cfg, ts.run(log, cfg, "smoother", reference=ref), ref)
    return _SCENARIO_CACHE[name]


def _estimated(name, est, opts):
    """``(result, runtime)`` of one scenario run, made once for both of its scorings."""
    from odofuse.rundir import estimate

    key = (name, est)
    if key not in _ESTIMATE_CACHE:
        log, cfg = _scenario_and_smoother(name)[:2]
        _ESTIMATE_CACHE[key] = estimate(ts.run_config(cfg, est, opts), log)
    return _ESTIMATE_CACHE[key]


def _scenario_params(known: set, reason: str) -> list:
    """Every (scenario, estimator) pair of the trust set; the ``known`` ones strict xfails."""
    xfail = pytest.mark.xfail(reason=f"known silent failure (issue 10): {reason}", strict=True)
    return [
        pytest.param(n, e, o, marks=[xfail] if (n, e) in known else [], id=f"{n}-{e}")
        for n in ts.SIMULATED
        for e, o in _TRUST_ESTIMATORS
    ]


@pytest.mark.parametrize(
    ("name", "est", "opts"),
    _scenario_params(KNOWN_SILENT, "the filter alone, cross-check off: still silent live"),
)
def test_scenarios_have_no_silent_failure(name, est, opts):
    """The estimator alone (filter alone, cross-check off): what a live pipeline has."""
    log, cfg, smoother, _ = _scenario_and_smoother(name)
    ref = smoother["ate_rmse_m"]
    m = ts.run(log, cfg, est, opts, check=False, estimated=_estimated(name, est, opts))
    assert m["cross_check"] == {"skipped": "off (options.cross_check.smoother)"}
    assert ts.judge(m, ref) != "SILENT", (m["ate_rmse_m"], ref, m["nees_position_mean"])


#: Pairs that are silent through ``odofuse run`` too (strict xfails; docs/trust.md section 6):
#: none since session 33. The accuracy ratio is advice, never a finding (issue 25): every run of
#: :data:`SMOOTHER_ADVISED` holds and gets the advice (the test asserts it). Under the issue-10
#: rule the second opinion flagged such runs, with 30 false alarms among 42 holding fused runs
#: (docs/trust.md 6.4).
KNOWN_SILENT_CHECKED: set = set(KNOWN_SILENT)


@pytest.mark.parametrize(
    ("name", "est", "opts"),
    _scenario_params(
        KNOWN_SILENT_CHECKED, "through odofuse run: the smoother's sigma exceeds its error"
    ),
)
def test_scenarios_as_odofuse_run_does_have_no_silent_failure(name, est, opts):
    """The same runs through the path of ``odofuse run`` (rundir.checked_metrics), with the
    batch smoother's second opinion (cross_check auto)."""
    log, cfg, smoother, reference = _scenario_and_smoother(name)
    m = ts.run(log, cfg, est, opts, reference=reference, estimated=_estimated(name, est, opts))
    verdict = ts.judge(m, smoother["ate_rmse_m"])
    if (name, est) in SMOOTHER_ADVISED:  # what the filter alone missed, the advice says
        assert any("more accurate" in a for a in m["advice"]), m["advice"]
    assert verdict != "SILENT", (m["ate_rmse_m"], smoother["ate_rmse_m"], m["cross_check"])


@pytest.mark.parametrize("name", ts.SIMULATED)
def test_the_smoother_yardstick_has_no_silent_failure(name):
    """The batch smoother is the others' RMSE reference, so it is judged on its NEES alone."""
    m = _scenario_and_smoother(name)[2]
    assert ts.judge(m, math.inf) != "SILENT", (m["ate_rmse_m"], m["nees_position_mean"])


def test_judge_holds_fused_estimators_to_the_smoother_and_dead_reckoning_to_its_nees():
    # issue 25 item 6: consistent and within 5x of the best on the log holds (4x: was SILENT
    # under the issue-10 rule of 2x), beyond 5x is a divergence
    within = {"estimator": "ekf", "ate_rmse_m": 0.4, "nees_position_mean": 2.0, "status": "ok"}
    assert ts.judge(within, 0.1) == "holds"
    assert ts.judge({**within, "ate_rmse_m": 0.51}, 0.1) == "SILENT"
    assert not ts.accurate(within, 0.1) and ts.accurate(within, 0.2)
    honest_drift = {"ate_rmse_m": 0.8, "nees_position_mean": 5.9, "status": "ok"}
    assert ts.judge({**honest_drift, "estimator": "dead_reckoning"}, 0.13) == "holds"
    assert ts.judge({**honest_drift, "estimator": "ekf"}, 0.13) == "SILENT"
    overconfident = {"ate_rmse_m": 0.1, "nees_position_mean": 12.0, "status": "ok"}
    assert ts.judge({**overconfident, "estimator": "dead_reckoning"}, 0.13) == "SILENT"
    assert ts.judge({**overconfident, "estimator": "ekf", "status": "degraded"}, 1) == "degraded"
    assert (
        ts.judge({"estimator": "ekf", "ate_rmse_m": 0.2, "nees_position_mean": 2}, 0.1) == "holds"
    )


def test_run_config_overrides_a_typed_block_of_a_config_read_from_a_file():
    # bench_trust.py --particles 1000 on Plaza2 (plaza1-particle.yaml, whose options block is
    # typed) crashed with "'ParticleOptions' object is not iterable" (session 28)
    from odofuse.config import load_config

    cfg = load_config(ts.ROOT / "configs" / "plaza1-particle.yaml")
    before = cfg.estimator_options("particle")
    run = ts.run_config(cfg, "particle", {"particles": 200})
    after = run.estimator_options("particle")
    assert after.particles == 200 and before.particles == 1000
    assert dataclasses.replace(after, particles=before.particles) == before  # the rest kept
    with pytest.raises(ConfigError, match="particles"):
        ts.run_config(cfg, "particle", {"particles": 0})


def test_localizer_health_is_live():
    from odofuse.estimators.assembly import build

    log, cfg = ts.simulated("stuck_encoder", laps=1)
    from odofuse.estimators.ekf import make_backend

    loc, t, U = build(cfg, log, "ekf", make_backend)
    assert loc.health().status == "ok"
    from odofuse.estimators.localizer import events

    streams = [s for s in cfg.sensors if s in log.streams]
    for te, kind, stream, i in events(log, t, U, streams):
        if kind == 1:
            loc.add_odometry(te, U[i])
        else:
            loc.add_measurement(stream, log.streams[stream].row(i))
    h = loc.health()
    assert h.status in ("ok", "degraded") and all(hasattr(f, "line") for f in h.findings)


@pytest.mark.slow(seconds=15)  # 20,000 particle steps in Python, 14.2 s (2026-12-04, AMD EPYC)
def test_particle_filter_with_a_gyro_keeps_positive_definite_covariances():
    loc = gyro_localizer(ParticleBackend, 20_000, particles=50, name="particle")
    P = loc.trajectory().covariances
    assert np.linalg.eigvalsh(P[1:]).min() > 0
    assert not [f for f in loc.health().findings if f.check == "covariance"]


@pytest.mark.slow(seconds=160)  # 10^6 filter steps compiled, 160 s in the suite (was 287 s)
def test_particle_filter_one_million_gyro_steps_never_non_pd():
    # On the compiled kernels: the path an offline run of this size takes (``compiled: auto``
    # compiles from 5e6 particle-rows; this is 2e7), and the numpy path's equal to 1e-9
    # (tests/test_compiled_particle.py); 20,000 numpy steps are checked just above.
    loc = gyro_localizer(ParticleBackend, 1_000_000, particles=20, name="particle", compiled="on")
    eig = np.linalg.eigvalsh(loc.trajectory().covariances[1:])
    assert eig.min() > 0 and math.isfinite(eig.max())
