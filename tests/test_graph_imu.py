"""High-rate gyros in the graph back ends (issue 14 item 4).

Gyro samples between keyframes are pre-integrated into one heading-increment factor per
keyframe interval with the bias as a variable, so the keyframes follow the keyframe policy,
not the gyro rate, and the factors are built-in GTSAM ones. High-rate compass readings move to
their nearest keyframe through the gyro (or wheel) rotation and are averaged; two gyros each
keep their own bias in the graph, and the filters refuse the second.
"""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from graph_sim import simulated_run  # noqa: E402

from odofuse.estimators import run_estimator  # noqa: E402
from odofuse.estimators.graph.custom_factors import gyro_increment_factor  # noqa: E402
from odofuse.estimators.graph.keyframes import preintegrate_gyro  # noqa: E402
from odofuse.evaluation import metrics  # noqa: E402
from odofuse.testing import numerical_jacobian  # noqa: E402

X, C = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.C

SCENARIO = {
    "seed": 9,
    "dt": 0.01,
    "robot": {"drive": "differential", "wheel_radius": 0.04, "track_width": 0.235},
    "path": {"kind": "figure_eight", "radius": 3.0, "speed": 0.4, "laps": 1},
    "systematic": {"E_d": 1.002, "E_b": 1.01},
    "nonsystematic": {"k": 1.0e-5},
    "sensors": {
        "gyro": {"sigma": 0.005, "bias": 0.01, "rate": 100.0},  # Hz
        "gps": {"sigma": 0.5, "rate": 1.0},
    },
}


def test_preintegration_matches_piecewise_sums():
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.005, 0.02, 400))
    t_prev = np.r_[0.0, t[:-1]]
    wz, var = rng.normal(0.0, 0.5, t.size), rng.uniform(1e-6, 1e-4, t.size)
    kt = np.unique(np.r_[0.0, rng.uniform(0.0, t[-1], 30), t[-1]])
    interval, dtheta, v, T, samples = preintegrate_gyro(t_prev, t, wz, var, kt)
    # reference: overlap of every sample with every keyframe interval, one by one
    ref = np.zeros((kt.size - 1, 3))
    for k in range(t.size):
        for i in range(kt.size - 1):
            tau = min(t[k], kt[i + 1]) - max(t_prev[k], kt[i])
            if tau > 0:
                dt = t[k] - t_prev[k]
                ref[i] += (wz[k] * tau, var[k] * dt * tau, tau)
    np.testing.assert_array_equal(interval, np.flatnonzero(ref[:, 2] > 0))
    np.testing.assert_allclose(dtheta, ref[interval, 0], atol=1e-12)
    np.testing.assert_allclose(v, ref[interval, 1], rtol=1e-12)
    np.testing.assert_allclose(T, ref[interval, 2], rtol=1e-12)
    assert samples.sum() == t.size
    # the whole log: the sum of the increments is the sum of the samples, variance too
    assert np.isclose(dtheta.sum(), np.sum(wz * (t - t_prev)))
    assert np.isclose(v.sum(), np.sum(var * (t - t_prev) ** 2))


def test_gyro_increment_factor_jacobians_and_linear_form_agree():
    noise = gtsam.noiseModel.Isotropic.Sigma(1, 0.01)
    f = gyro_increment_factor(X(0), X(1), C(0), 0.8, 2.0, noise)
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose2(1.0, 2.0, 0.3))
    values.insert(X(1), gtsam.Pose2(1.5, 2.2, 1.05))
    values.insert(C(0), np.array([0.02]))
    e = f.unwhitenedError(values)
    assert np.isclose(e[0], 1.05 - 0.3 + 0.02 * 2.0 - 0.8)
    lin = f.linearize(values)
    A = lin.jacobian()[0] * 0.01  # un-whiten
    keys = [X(0), X(1), C(0)]

    def err(d):
        v = gtsam.Values()
        v.insert(X(0), values.atPose2(X(0)).retract(d[0:3]))
        v.insert(X(1), values.atPose2(X(1)).retract(d[3:6]))
        v.insert(C(0), values.atVector(C(0)) + d[6:7])
        return f.unwhitenedError(v)

    np.testing.assert_allclose(A, numerical_jacobian(err, np.zeros(7)), atol=1e-8)
    assert [lin.keys()[i] for i in range(3)] == keys


def _odometry_python_factors(res, odometry_calibration) -> int:
    """The Python factors of a run's odometry: one per keyframe interval when it is
    calibrated (``auto``, the default, with the GPS), none otherwise."""
    assert ("wheel_radius_ratio" in res.extra["calibration"]) == (odometry_calibration == "auto")
    return res.extra["keyframes"] - 1 if odometry_calibration == "auto" else 0


@pytest.mark.parametrize("odometry_calibration", [False, "auto"])
@pytest.mark.parametrize("estimator", ["smoother", "isam2", "fixed_lag"])
def test_keyframes_follow_the_policy_not_the_gyro_rate(estimator, odometry_calibration):
    log, cfg = simulated_run(
        SCENARIO,
        9,
        estimator,
        options={"odometry_calibration": odometry_calibration},
        sensors={"gyro": {"calibrate": True}},
    )
    res = run_estimator(estimator, log, cfg)
    m = metrics(res, log)
    gyro = log.streams["gyro"]
    span = log.streams["wheels"].t[-1] - log.streams["wheels"].t[0]
    # 1 s keyframes plus the GPS times and the gyro stream's two ends
    assert res.extra["keyframes"] <= span + len(log.streams["gps"]) + 4
    assert len(gyro) > 80 * res.extra["keyframes"]  # 100 Hz against ~1 Hz
    # the gyro's factors are built in (a calibrated odometry's are Python)
    assert res.extra["python_factors"] == _odometry_python_factors(res, odometry_calibration)
    assert res.used["gyro"] == len(gyro) - 1 and res.rejected["gyro"] == 1
    assert abs(res.extra["calibration"]["gyro_bias"] - 0.01) < 1e-3
    assert m["ate_rmse_m"] < 0.15
    assert m["status"] == "ok", m["warnings"]
    if estimator != "fixed_lag":  # (fixed-lag poses come from different windows)
        # the gyro alone fixes the relative headings: its residuals are small, never large
        assert res.extra["residuals"]["gyro"]["median_ratio"] < 4.0


@pytest.mark.parametrize("odometry_calibration", [False, "auto"])
def test_robust_gyro_with_bias_uses_the_python_factor(odometry_calibration):
    log, cfg = simulated_run(
        SCENARIO,
        9,
        "smoother",
        options={"robust": {"gyro": "huber"}, "odometry_calibration": odometry_calibration},
        sensors={"gyro": {"calibrate": True}},
    )
    res = run_estimator("smoother", log, cfg)
    gyro = res.extra["python_factors"] - _odometry_python_factors(res, odometry_calibration)
    assert 0 < gyro < res.extra["keyframes"] + 5
    assert abs(res.extra["calibration"]["gyro_bias"] - 0.01) < 1e-3


def test_attached_headings_variance_matches_monte_carlo():
    """Headings moved to their nearest keyframe through a gyro: the averaged heading is
    unbiased and its stated variance is the spread over seeded repetitions (white rate noise,
    reading noise, bias prior), keyframe by keyframe."""
    from odofuse.estimators.graph.keyframes import attach_headings, gyro_rotation_track

    rng = np.random.default_rng(21)
    dt, sig_rate, sig_c, bias_sigma = 0.01, 0.02, 0.05, 0.01
    edges = np.round(np.arange(0.0, 6.0 + dt / 2, dt), 9)  # gyro sample boundaries
    t_prev, t_g = edges[:-1], edges[1:]
    theta = 0.8 * np.sin(0.7 * edges)  # true heading at the boundaries
    rate = np.diff(theta) / dt  # the true mean rate of each sample
    t_c = edges[1::2]  # 50 Hz readings on sample boundaries
    kt = np.array([0.0, 1.0, 2.3, 3.0, 4.5, 6.0])
    trials = 1500
    errs = []
    for _ in range(trials):
        b = rng.normal(0.0, bias_sigma)
        wz = rate + b + rng.normal(0.0, sig_rate, rate.size)
        track = (*gyro_rotation_track(t_prev, t_g, wz, np.full(wz.size, sig_rate**2)), bias_sigma)
        z = theta[1::2] + rng.normal(0.0, sig_c, t_c.size)
        k, zk, var, count, first, last = attach_headings(
            t_c, z, np.full(t_c.size, sig_c**2), kt, [track]
        )
        errs.append(np.angle(np.exp(1j * (zk - theta[np.round(kt[k] / dt).astype(int)]))))
    errs = np.array(errs)
    np.testing.assert_array_equal(k, np.arange(kt.size))  # every keyframe gets readings
    assert count.sum() == t_c.size and first[0] == 0 and last[-1] == t_c.size - 1
    # each reading went to its nearest keyframe
    nearest = np.argmin(np.abs(t_c[:, None] - kt[None, :]), axis=1)
    np.testing.assert_array_equal(count, np.bincount(nearest, minlength=kt.size))
    se = np.sqrt(var / trials)
    assert np.all(np.abs(errs.mean(axis=0)) < 4 * se)
    ratio = errs.var(axis=0) / var
    print("empirical / stated variance per keyframe:", np.round(ratio, 3))
    assert np.all(np.abs(ratio - 1.0) < 5 * np.sqrt(2.0 / trials))
    # the averaging is worth it: far below one reading's variance
    assert np.all(var[1:-1] < 0.2 * sig_c**2)


def _two_gyros(bias2=-0.015, sigma2=0.004):
    """SCENARIO's log with a second IMU ``gyro_2`` (50 Hz, its own bias and noise)."""
    import dataclasses

    from odofuse.io.log import Stream

    log, cfg = simulated_run(SCENARIO, 9, "smoother")
    gt = log.groundtruth
    rng = np.random.default_rng(31)
    t2 = np.arange(gt.t[0] + 0.02, gt.t[-1], 0.02)
    theta = np.interp(np.r_[t2[0] - 0.02, t2], gt.t, np.unwrap(gt["theta"]))
    wz = np.diff(theta) / 0.02 + bias2 + rng.normal(0.0, sigma2, t2.size)
    streams = {**log.streams, "gyro_2": Stream("gyro_2", "sim", t2, ("wz",), wz[:, None])}
    return dataclasses.replace(log, streams=streams)


@pytest.mark.parametrize("odometry_calibration", [False, "auto"])
@pytest.mark.parametrize("estimator", ["smoother", "isam2", "fixed_lag"])
def test_two_gyros_each_with_its_own_bias(estimator, odometry_calibration):
    """Two IMUs (gyro, gyro_2): each pre-integrated, each with its bias variable."""
    log = _two_gyros()
    sensors = {
        "gyro": {"sigma": 0.005, "calibrate": True},
        "gyro_2": {"model": "gyro", "sigma": 0.004, "calibrate": True},
    }
    options = {"odometry_calibration": odometry_calibration}
    _, cfg = simulated_run(SCENARIO, 9, estimator, options=options, sensors=sensors)
    res = run_estimator(estimator, log, cfg)
    cal = res.extra["calibration"]
    assert set(cal) >= {"gyro_bias", "gyro_bias:gyro_2"}
    assert abs(cal["gyro_bias"] - 0.01) < 1e-3
    assert abs(cal["gyro_bias:gyro_2"] + 0.015) < 1e-3
    assert res.used["gyro"] == len(log.streams["gyro"]) - 1
    assert res.used["gyro_2"] == len(log.streams["gyro_2"]) - 1
    assert res.extra["python_factors"] == _odometry_python_factors(res, odometry_calibration)
    gyro = log.streams["gyro"]
    assert len(gyro) > 80 * res.extra["keyframes"]  # both pre-integrated: 1 s keyframes


def test_filters_refuse_a_second_gyro():
    from odofuse.errors import ConfigError

    log = _two_gyros()
    blocks = {"gyro_2": {"model": "gyro", "sigma": 0.004}}
    for estimator in ("ekf", "ukf", "particle"):
        _, cfg = simulated_run(SCENARIO, 9, estimator, sensors=blocks)
        with pytest.raises(ConfigError, match=r"key 'sensors.gyro_2': the filters fuse one gyro"):
            run_estimator(estimator, log, cfg)


def test_wheel_rotation_track_is_the_preintegrated_heading():
    """The wheels' rotation track between two odometry times is the heading part of the
    pre-integrated odometry (its variance the theta-theta covariance entry)."""
    from odofuse.estimators.common import odometry_inputs
    from odofuse.estimators.graph.keyframes import preintegrate, wheel_rotation_track
    from odofuse.motion import motion_model_from_config

    log, cfg = simulated_run(SCENARIO, 9, "smoother")
    model = motion_model_from_config(cfg)
    t_odo, U = odometry_inputs(log, model)
    kt = t_odo[::37]
    deltas, covs = preintegrate(t_odo, U, model, kt)
    knots, theta, var = wheel_rotation_track(t_odo, U, model)
    np.testing.assert_allclose(np.diff(np.interp(kt, knots, theta)), deltas[:, 2], atol=1e-12)
    np.testing.assert_allclose(np.diff(np.interp(kt, knots, var)), covs[:, 2, 2], rtol=1e-9)


def test_high_rate_compass_without_gyro_rides_on_the_wheels():
    """A 20 Hz compass, no gyro: attached through the wheels' heading to 1 s keyframes, as
    accurate as the same readings each made a keyframe (``keyframe_dt: 0``, the old graph)."""
    scenario = {
        **SCENARIO,
        "sensors": {"compass": {"sigma": 0.05, "rate": 20.0}, "gps": {"sigma": 0.5, "rate": 1.0}},
    }
    res, err = {}, {}
    for dt in (1.0, 0.0):
        log, cfg = simulated_run(scenario, 9, "smoother", options={"keyframe_dt": dt})
        res[dt] = run_estimator("smoother", log, cfg)
        err[dt] = metrics(res[dt], log)["ate_rmse_m"]
        assert res[dt].used["compass"] == len(log.streams["compass"])
    span = log.streams["wheels"].t[-1] - log.streams["wheels"].t[0]
    print("keyframes", {k: r.extra["keyframes"] for k, r in res.items()}, "RMSE", err)
    assert res[1.0].extra["keyframes"] <= span + len(log.streams["gps"]) + 2
    assert res[0.0].extra["keyframes"] >= len(log.streams["compass"])
    assert err[1.0] < 1.15 * err[0.0]
    summary = res[1.0].extra["residuals"]["compass"]
    assert summary["beyond_999"] <= 0.02  # the averaged readings' variance holds


def test_attached_compass_factor_waits_for_its_last_reading():
    """iSAM2 adds an averaged compass factor with the first keyframe at or after its last
    reading: no update sees readings from its future."""
    from odofuse.estimators.graph.problem import build_problem

    scenario = {**SCENARIO, "sensors": {"compass": {"sigma": 0.05, "rate": 20.0}}}
    log, cfg = simulated_run(scenario, 9, "isam2")
    p = build_problem(log, cfg, "isam2")
    tc = log.streams["compass"].t
    meas = [m for m in p.measurements if m.stream == "compass"]
    assert sum(m.rows for m in meas) == len(tc)
    later = 0
    for m in meas:
        added = m.keyframe if m.added_at is None else m.added_at
        last = tc[m.index + m.rows - 1]
        assert p.kt[added] >= last and added - m.keyframe in (0, 1)
        later += added > m.keyframe
    assert later > len(meas) // 2  # most keyframes have readings after them
