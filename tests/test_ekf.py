"""EKF: prediction == the shared motion model, Joseph update, gating, NEES, SPD, Plaza1."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
from scipy.stats import chi2

from odofuse.config import RunConfig
from odofuse.estimators.ekf import EkfBackend, FastIncrement, _exp_coeffs
from odofuse.estimators.ekf import run as run_ekf
from odofuse.io.log import SensorLog, Stream
from odofuse.measurements import BeaconRange, CompassHeading, GpsPosition
from odofuse.motion import motion_model_from_config

BEACONS = {0: np.array([20.0, 0.0]), 1: np.array([0.0, 25.0]), 2: np.array([-15.0, -10.0])}


def _motion(drive="increments", integrator="exact", k=(1e-3, 1e-4), floor=1e-8, **geometry):
    cfg = RunConfig(
        log="x",
        robot={"drive": drive, **geometry},
        # k_theta_ds: 0 keeps the pure per-input model these statistics were written for.
        motion={"integrator": integrator, "k": list(k), "var_floor": floor}
        | ({"k_theta_ds": 0.0} if drive == "increments" else {}),
    )
    return motion_model_from_config(cfg)


def simulate(
    seed, steps=300, k=(1e-3, 1e-4), sigma=0.3, every=2, scale=1.0, offset=0.0, floor=1e-8
):
    """Truth and a log for the increments drive: noisy odometry, ranges to 3 beacons.

    The odometry noise is drawn from the filter's own error model (var = k |u| + floor), so
    a consistent filter must show chi-square NEES.
    """
    rng = np.random.default_rng(seed)
    model = _motion(k=k, floor=floor)
    dt = 0.1
    t = dt * np.arange(1, steps + 1)
    u_true = np.column_stack(
        [0.2 + 0.05 * np.sin(0.05 * np.arange(steps)), 0.03 * np.cos(0.02 * np.arange(steps))]
    )
    var = model.errors.variances(model.drive, u_true)
    u_meas = u_true + rng.normal(0.0, np.sqrt(var))
    pose = np.array([1.0, -2.0, 0.3])
    truth = [pose]
    for u in u_true:
        pose = pose.copy()
        delta, _ = model.increment(u)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose = np.array(
            [
                pose[0] + c * delta[0] - s * delta[1],
                pose[1] + s * delta[0] + c * delta[1],
                (pose[2] + delta[2] + math.pi) % (2 * math.pi) - math.pi,
            ]
        )
        truth.append(pose)
    truth = np.array(truth)
    rows = []
    for i in range(every - 1, steps, every):
        b = (i // every) % 3
        d = np.hypot(*(truth[i + 1, :2] - BEACONS[b]))
        rows.append((t[i], b, scale * d + offset + rng.normal(0.0, sigma)))
    rows = np.array(rows).reshape(-1, 3)
    log = SensorLog(
        "sim",
        {
            "odometry": Stream("odometry", "sim", t, ("ds", "dtheta"), u_meas),
            "ranges": Stream("ranges", "sim", rows[:, 0], ("id", "range"), rows[:, 1:]),
        },
        BEACONS,
        Stream("groundtruth", "sim", np.r_[0.0, t], ("x", "y", "theta"), truth),
        {},
        truth[0],
    )
    return log, truth


def sim_config(
    k=(1e-3, 1e-4), sigma=0.3, estimator="ekf", calibrate=False, sigma0=0.05, floor=1e-8, **options
):
    ranges = {"sigma": sigma, "gate": 0.9999}
    if calibrate:
        ranges.update(calibrate=True, scale_sigma=0.05, offset_sigma=0.5)
    return RunConfig(
        log="sim",
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": list(k), "var_floor": floor, "k_theta_ds": 0.0},
        estimator=estimator,
        initial={"sigma": [sigma0, sigma0, sigma0 / 5]},
        sensors={"ranges": ranges},
        # the simulated odometry has no systematic error: the config says its calibration is
        # known (odometry_calibration defaults to auto, on with the ranges)
        options={estimator: {"odometry_calibration": False, **options}},
        source="sim.yaml",
    )


# ------------------------------------------------------------------------------ prediction
@pytest.mark.parametrize("integrator", ["euler", "rk2", "exact"])
@pytest.mark.parametrize(
    "drive,geometry,u",
    [
        ("increments", {}, [0.2, 0.05]),
        ("increments", {}, [0.2, 0.0]),
        ("differential", {"wheel_radius": 0.05, "track_width": 0.3}, [3.0, 3.4]),
    ],
)
def test_predict_equals_the_motion_model(integrator, drive, geometry, u):
    model = _motion(drive, integrator, k=(1e-3, 2e-3), **geometry)
    pose = np.array([1.0, 2.0, math.pi - 0.01])
    P = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, -0.003], [0.002, -0.003, 0.01]])
    b = EkfBackend(model, {}, pose, P, np.zeros(3))
    assert b._fast is not None  # linear drives take the scalar path
    b.predict(np.array(u), 0.1)
    pose_ref, P_ref, _, _ = model.predict(pose, P, np.array(u))
    np.testing.assert_allclose(b.mean(), pose_ref, atol=1e-12)
    np.testing.assert_allclose(b.cov(), P_ref, atol=1e-14)


@pytest.mark.parametrize("w", [0.0, 1e-9, 1e-6, 1e-3, 1e-2 - 1e-12, 1e-2, 1.0, -2.5])
def test_fast_increment_matches_model_increment(w):
    model = _motion()
    fast = FastIncrement(model)
    assert fast.ok
    u = np.array([0.3, w])
    d, J, var = fast(u)
    d0, J0 = model.increment(u)
    np.testing.assert_allclose(d, d0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(J, J0, rtol=0, atol=1e-13)
    np.testing.assert_allclose(var, model.errors.variances(model.drive, u), rtol=1e-15)
    # sin(w)/w and (1-cos w)/w at reference values
    A, B, _, _ = _exp_coeffs(1.0)
    assert A == pytest.approx(math.sin(1.0)) and B == pytest.approx(1 - math.cos(1.0))


def test_augmented_states_keep_their_cross_covariance_and_walk():
    model = _motion()
    m = BeaconRange("ranges", 0.3, landmarks=BEACONS, calibrate=True, scale_walk=0.01)
    m = m.bind({"range_scale": 3, "range_offset": 4})
    P = np.diag([0.04, 0.04, 0.01, 0.0025, 0.25])
    P[0, 3] = P[3, 0] = 0.001
    b = EkfBackend(
        model, {"r": m}, np.array([0, 0, 0.2, 1.0, 0.0]), P, np.array([0, 0, 0, 1e-4, 0])
    )
    b.predict(np.array([0.2, 0.05]), 2.0)
    pose_ref, P_ref, F_p, _ = model.predict(np.array([0, 0, 0.2]), P[:3, :3], np.array([0.2, 0.05]))
    np.testing.assert_allclose(b.cov()[:3, :3], P_ref, atol=1e-14)
    np.testing.assert_allclose(b.cov()[:3, 3:], F_p @ P[:3, 3:], atol=1e-15)
    assert b.cov()[3, 3] == pytest.approx(0.0025 + 2.0 * 1e-4)
    assert b.cov()[4, 4] == 0.25


# ------------------------------------------------------------------------------ update
def test_update_is_joseph_form_and_wraps_theta():
    model = _motion()
    m = CompassHeading("compass", 0.05)
    x0 = np.array([0.0, 0.0, math.pi - 0.02])
    P0 = np.diag([0.1, 0.1, 0.05**2])
    b = EkfBackend(model, {"c": m}, x0, P0, np.zeros(3))
    row = {"t": 0.0, "heading": -math.pi + 0.02}  # 0.04 rad ahead, across +-pi
    accepted, nis = b.update(m, row)
    assert accepted and nis == pytest.approx(0.04**2 / (2 * 0.05**2))
    assert -math.pi <= b.mean()[2] < math.pi
    assert b.mean()[2] == pytest.approx(-math.pi, abs=1e-12) or b.mean()[2] == pytest.approx(
        math.pi, abs=1e-12
    )
    H = np.array([[0.0, 0.0, 1.0]])
    K = P0 @ H.T / (P0[2, 2] + 0.05**2)
    IKH = np.eye(3) - K @ H
    np.testing.assert_allclose(b.cov(), IKH @ P0 @ IKH.T + 0.05**2 * K @ K.T, atol=1e-15)


def test_gate_rejects_an_outlier_and_leaves_the_state():
    model = _motion()
    m = GpsPosition("gps", 0.5, gate=0.999)
    b = EkfBackend(model, {"g": m}, np.zeros(3), np.eye(3) * 0.01, np.zeros(3))
    x0, P0 = b.mean().copy(), b.cov().copy()
    accepted, nis = b.update(m, {"t": 0.0, "x": 30.0, "y": 0.0})
    assert not accepted and nis > chi2.ppf(0.999, 2)
    np.testing.assert_array_equal(b.mean(), x0)
    np.testing.assert_array_equal(b.cov(), P0)
    assert b.update(m, {"t": 0.0, "x": 0.3, "y": -0.2})[0]


def test_run_counts_used_and_rejected_per_sensor():
    log, _ = simulate(1, steps=200)
    ranges = log.streams["ranges"]
    values = ranges.values.copy()
    values[[10, 40, 70], 1] += 25.0  # three gross outliers
    log.streams["ranges"] = Stream("ranges", "sim", ranges.t, ranges.columns, values)
    res = run_ekf(log, sim_config())
    assert res.rejected["ranges"] == 3
    assert res.used["ranges"] == len(ranges) - 3
    assert res.estimator == "ekf" and len(res.trajectory) == 201


def test_range_scale_and_offset_are_learnt():
    log, truth = simulate(3, steps=1500, scale=1.04, offset=0.3, sigma=0.2, every=1)
    res = run_ekf(log, sim_config(sigma=0.2, calibrate=True))
    cal = res.extra["calibration"]
    assert abs(cal["range_scale"]["value"] - 1.04) < 3 * cal["range_scale"]["sigma"]
    assert abs(cal["range_offset"]["value"] - 0.3) < 3 * cal["range_offset"]["sigma"]
    assert cal["range_scale"]["sigma"] < 0.01


# ------------------------------------------------------------------------------ statistics
def test_monte_carlo_nees_inside_95_percent_chi_square_bounds():
    runs, steps = 40, 300
    nees = np.empty((runs, steps + 1))
    sigma0 = np.array([0.05, 0.05, 0.01])
    for r in range(runs):
        log, truth = simulate(100 + r, steps=steps)
        # The initial estimate is drawn from its own prior, like every later error.
        pose0 = truth[0] + np.random.default_rng(1000 + r).normal(0.0, sigma0)
        cfg = dataclasses.replace(
            sim_config(), initial={"pose": list(pose0), "sigma": list(sigma0)}
        )
        res = run_ekf(log, cfg)
        tr = res.trajectory
        err = tr.poses - truth
        err[:, 2] = (err[:, 2] + math.pi) % (2 * math.pi) - math.pi
        nees[r] = np.einsum("ni,nij,nj->n", err, np.linalg.inv(tr.covariances), err)
    anees = nees.mean(axis=0)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * runs) / runs
    inside = np.mean((anees >= lo) & (anees <= hi))
    assert inside >= 0.9, f"only {inside:.2%} of time steps inside [{lo:.2f}, {hi:.2f}]"
    assert lo < nees.mean() < hi


@pytest.mark.slow
def test_covariance_stays_symmetric_positive_definite_over_a_million_steps():
    model = _motion(k=(1e-2, 1e-3))
    m = BeaconRange("ranges", 0.5, landmarks=BEACONS, calibrate=True).bind(
        {"range_scale": 3, "range_offset": 4}
    )
    P0 = np.diag([0.01, 0.01, 0.01, 0.0025, 0.25])
    b = EkfBackend(model, {"r": m}, np.array([0.0, 0.0, 0.0, 1.0, 0.0]), P0, np.zeros(5))
    rng = np.random.default_rng(7)
    u = np.array([0.2, 0.05])
    rows = [{"t": 0.0, "id": i, "range": 0.0} for i in range(3)]
    for k in range(1_000_000):
        b.predict(u, 0.1)
        if k % 20 == 0:  # a range every 2 s of driving
            row = rows[(k // 20) % 3]
            x = b.mean()
            row["range"] = float(np.hypot(*(x[:2] - BEACONS[row["id"]]))) + rng.normal(0, 0.5)
            b.update(m, row)
        if k % 1000 == 999:
            P = b.cov()
            # The prediction keeps P exactly symmetric; filterpy's Joseph update leaves
            # rounding-level asymmetry, which must not accumulate.
            assert np.max(np.abs(P - P.T)) <= 1e-13 * np.max(np.abs(P))
            np.linalg.cholesky(P)  # raises if not positive definite
    assert np.all(np.linalg.eigvalsh(b.cov()) > 0)


# ------------------------------------------------------------------------------ Plaza1
@functools.cache
def _plaza_rmse(estimator, config=None, log_name="builtin:plaza1"):
    """Position RMSE, result and log of ``configs/<config>`` (default ``plaza1-<estimator>``)
    run unchanged but for ``log:`` on ``log_name``; cached (several tests share a run)."""
    import pathlib

    from odofuse.config import load_config
    from odofuse.estimators import get_estimator
    from odofuse.io.builtin import load_builtin

    root = pathlib.Path(__file__).resolve().parents[1]
    log = load_builtin(log_name)
    cfg = load_config(root / "configs" / (config or f"plaza1-{estimator}.yaml"))
    res = get_estimator(estimator)(log, dataclasses.replace(cfg, log=log_name))
    tr, gt = res.trajectory, log.groundtruth
    gx, gy = np.interp(tr.t, gt.t, gt["x"]), np.interp(tr.t, gt.t, gt["y"])
    rmse = math.sqrt(np.mean((tr.poses[:, 0] - gx) ** 2 + (tr.poses[:, 1] - gy) ** 2))
    return rmse, res, log


def test_plaza1_ekf_rmse_at_most_30_cm():
    # The hand-written Plaza1-only config (the reference of issue 11's 1.3x target).
    rmse, res, log = _plaza_rmse("ekf", "handtuned-plaza1-ekf.yaml")
    assert rmse <= 0.30
    # The ranges' systematic scale error (~7 %) is learnt, not absorbed into the pose.
    assert 1.03 < res.extra["calibration"]["range_scale"]["value"] < 1.10
    assert res.used["ranges"] + res.rejected["ranges"] == len(log.streams["ranges"])


@pytest.mark.slow
@pytest.mark.parametrize("log_name", ["builtin:plaza1", "builtin:plaza2"])
def test_one_plaza_ekf_config_serves_both_runs(log_name):
    # configs/plaza1-ekf.yaml with only log: changed (issue 11). Plaza1: within 1.3x of the
    # hand-written Plaza1-only config. Plaza2 has no hand-tuned reference (tuning on it would
    # be the one-log pattern again): pinned near its measured 0.328 m, against 0.71 m (NEES
    # 7.4) for the Plaza1-only config there. Position NEES within 0.5-2x its dimension.
    from odofuse.evaluation import metrics

    rmse, res, log = _plaza_rmse("ekf", None, log_name)
    if log_name == "builtin:plaza1":
        assert rmse <= 1.3 * _plaza_rmse("ekf", "handtuned-plaza1-ekf.yaml")[0]
    else:
        assert rmse <= 0.35
    assert 1.0 <= metrics(res, log)["nees_position_mean"] <= 4.0
    assert 1.03 < res.extra["calibration"]["range_scale"]["value"] < 1.10


def test_gps_with_lever_arm_and_compass_end_to_end():
    log, truth = simulate(40, steps=400, k=(1e-2, 1e-3), every=1000)
    rng = np.random.default_rng(41)
    lever = np.array([0.4, 0.1])
    t = log.streams["odometry"].t
    idx = np.arange(9, 400, 10)
    th = truth[idx + 1, 2]
    ant = truth[idx + 1, :2] + np.column_stack(
        [
            np.cos(th) * lever[0] - np.sin(th) * lever[1],
            np.sin(th) * lever[0] + np.cos(th) * lever[1],
        ]
    )
    gps = ant + rng.normal(0.0, 0.5, ant.shape)
    heading = (th + rng.normal(0.0, 0.05, th.size) + math.pi) % (2 * math.pi) - math.pi
    streams = dict(log.streams)
    streams["gps"] = Stream("gps", "sim", t[idx], ("x", "y"), gps)
    streams["compass"] = Stream("compass", "sim", t[idx], ("heading",), heading[:, None])
    log = dataclasses.replace(log, streams=streams)
    base = sim_config(k=(1e-2, 1e-3))
    sensors = {"gps": {"sigma": 0.5, "lever_arm": lever.tolist()}, "compass": {"sigma": 0.05}}
    res = run_ekf(log, dataclasses.replace(base, sensors=sensors))
    dr = run_ekf(log, dataclasses.replace(base, sensors={}))
    err = np.hypot(*(res.trajectory.xy - truth[:, :2]).T)
    err_dr = np.hypot(*(dr.trajectory.xy - truth[:, :2]).T)
    assert res.used == {"gps": 40, "compass": 40}
    assert err[-100:].max() < 1.0 and err_dr[-100:].mean() > 2 * err[-100:].mean()
    e = res.trajectory.poses - truth
    e[:, 2] = (e[:, 2] + math.pi) % (2 * math.pi) - math.pi
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(res.trajectory.covariances), e)
    assert nees[50:].mean() < chi2.ppf(0.999, 3)
