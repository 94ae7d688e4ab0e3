"""Streaming Localizer: online == offline, step splitting, late measurements, REP-105, gyro."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from compiled_checks import feed
from compiled_checks import late as arrive_late
from test_ekf import sim_config, simulate

from odofuse import se2
from odofuse.errors import ConfigError
from odofuse.estimators import ekf, particle, ukf
from odofuse.estimators.assembly import build, events
from odofuse.io.log import SensorLog, Stream
from odofuse.motion import dead_reckon

BACKENDS = {"ekf": ekf, "ukf": ukf, "particle": particle}


def _cfg(estimator="ekf", **kw):
    # The streaming Localizer is compared bit for bit with the offline *Python* path; the
    # compiled EKF and UKF cores equal that path to 1e-9 (tests/test_compiled.py,
    # tests/test_compiled_ukf.py), not to the last bit.
    opts = {"particles": 200, "seed": 3} if estimator == "particle" else {}
    if estimator in ("ekf", "ukf"):
        opts["compiled"] = "off"
    opts.update(kw.pop("options", {}))
    return sim_config(estimator=estimator, **kw, **opts)


def _live_gps_config(sensors=None, **ekf_options):
    """A live EKF on 2-D increments and (by default) GPS at 0.5 m, no log
    (``Localizer.from_config``)."""
    from odofuse.config import RunConfig

    return RunConfig(
        log="live",
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": [1e-3, 1e-4], "var_floor": 1e-8},
        estimator="ekf",
        initial={"pose": [0.0, 0.0, 0.0], "sigma": [0.1, 0.1, 0.02]},
        sensors=sensors or {"gps": {"sigma": 0.5}},
        options={"ekf": ekf_options},
    )


def _stream(log, name, t, columns, values):
    streams = dict(log.streams)
    streams[name] = Stream(name, "sim", np.asarray(t, float), columns, np.asarray(values, float))
    return dataclasses.replace(log, streams=streams)


def _feed_online(log, cfg, estimator, order=None):
    loc, t, U = build(cfg, log, estimator, BACKENDS[estimator].make_backend)
    poses = []
    feed(loc, log, t, U, ["ranges", "gyro"], order, lambda loc: poses.append(loc.pose()))
    return loc, np.array(poses)


@pytest.mark.parametrize("estimator", ["ekf", "ukf", "particle"])
def test_streaming_equals_the_offline_run(estimator):
    log, _ = simulate(21, steps=200)
    cfg = _cfg(estimator)
    offline = BACKENDS[estimator].run(log, cfg)
    loc, poses_now = _feed_online(log, cfg, estimator)
    online = loc.result()
    np.testing.assert_array_equal(online.trajectory.poses, offline.trajectory.poses)
    np.testing.assert_array_equal(online.trajectory.covariances, offline.trajectory.covariances)
    # "Where am I now" after each odometry row is the trajectory as it was being built.
    np.testing.assert_array_equal(poses_now, offline.trajectory.poses[1:])
    assert online.used == offline.used and online.rejected == offline.rejected


def test_measurement_inside_a_step_splits_the_odometry_increment():
    log, _ = simulate(22, steps=3, every=1)
    t_odo = log.streams["odometry"].t
    # One range at 30 % of the second step.
    tm = t_odo[0] + 0.3 * (t_odo[1] - t_odo[0])
    log = _stream(log, "ranges", [tm], ("id", "range"), [[0, 19.0]])
    cfg = _cfg()
    res = ekf.run(log, cfg)
    loc, t, U = build(cfg, log, "ekf", ekf.make_backend)
    b, m = loc.backend, loc.models["ranges"]
    b.predict(U[0], t[1] - t[0])
    b.predict(0.3 * U[1], 0.3 * (t[2] - t[1]))
    b.update(m, log.streams["ranges"].row(0))
    b.predict(0.7 * U[1], 0.7 * (t[2] - t[1]))
    np.testing.assert_allclose(res.trajectory.poses[2], b.mean()[:3], atol=1e-15)
    np.testing.assert_allclose(res.trajectory.covariances[2], b.cov()[:3, :3], atol=1e-15)


@pytest.mark.parametrize("estimator", ["ekf", "particle"])
def test_late_measurements_inside_the_window_are_replayed(estimator):
    log, _ = simulate(23, steps=200)
    cfg = _cfg(estimator, options={"late_window": 1.0})
    offline = BACKENDS[estimator].run(log, cfg)
    loc, _ = _feed_online(log, cfg, estimator, order=arrive_late("ranges", 0.45))
    late = loc.result()
    assert late.extra["dropped_late"] == {}
    assert late.used == offline.used
    np.testing.assert_allclose(late.trajectory.poses, offline.trajectory.poses, atol=1e-12)


def test_measurements_older_than_the_window_are_counted_and_dropped():
    log, _ = simulate(24, steps=200)
    cfg = _cfg(options={"late_window": 0.3})
    loc, _ = _feed_online(log, cfg, "ekf", order=arrive_late("ranges", 0.5))
    res = loc.result()
    # Each range arrives 0.5 s late, when the filter is 0.4 s past it (odometry every 0.1 s),
    # except near the end of the log where the odometry stops earlier.
    t_end = log.streams["odometry"].t[-1]
    t_r = log.streams["ranges"].t
    late = np.minimum(t_r + 0.4, t_end) - t_r > 0.3 + 1e-9
    assert res.extra["dropped_late"]["ranges"] == late.sum() > 90
    assert res.used["ranges"] == (~late).sum()
    # Up to the first replayed range the filter is dead reckoning.
    odo = ekf.run(dataclasses.replace(log, streams={"odometry": log.streams["odometry"]}), cfg)
    first = t_r[~late].min()
    keep = res.trajectory.t < first
    np.testing.assert_allclose(res.trajectory.poses[keep], odo.trajectory.poses[keep], atol=1e-12)


def test_measurements_after_the_last_odometry_are_counted():
    log, _ = simulate(25, steps=50)
    t_end = log.streams["odometry"].t[-1]
    r = log.streams["ranges"]
    log = _stream(
        log, "ranges", np.r_[r.t, t_end + 1.0], r.columns, np.vstack([r.values, [0, 10.0]])
    )
    res = ekf.run(log, _cfg())
    assert res.extra["dropped_late"] == {"ranges": 1}


def test_odom_frame_is_dead_reckoning_and_map_to_odom_closes_the_loop():
    log, _ = simulate(26, steps=150)
    cfg = _cfg()
    loc, _ = _feed_online(log, cfg, "ekf")
    _, t, U = build(cfg, log, "ekf", ekf.make_backend)
    dr, _ = dead_reckon(loc.motion_model, log.initial_pose, np.zeros((3, 3)), U, with_cov=False)
    np.testing.assert_allclose(loc.odom_pose(), dr[-1], atol=1e-9)
    np.testing.assert_allclose(
        se2.compose(loc.map_to_odom(), loc.odom_pose()), loc.pose(), atol=1e-12
    )
    assert np.hypot(*(loc.pose()[:2] - dr[-1][:2])) > 1e-3  # the ranges did correct it


def _with_gyro(log, truth, bias, sigma, seed):
    """Add a gyro stream: mean true yaw rate over each odometry step, plus bias and noise."""
    rng = np.random.default_rng(seed)
    t = log.streams["odometry"].t
    t_all = np.r_[log.groundtruth.t[0], t]
    dth = se2.wrap(np.diff(truth[:, 2]))
    rate = dth / np.diff(t_all) + bias + rng.normal(0.0, sigma, t.size)
    return _stream(log, "gyro", t, ("wz",), rate[:, None])


def _heading_rmse(res, truth):
    return math.sqrt(np.mean(se2.wrap(res.trajectory.poses[:, 2] - truth[:, 2]) ** 2))


def test_gyro_as_a_measurement_with_bias_calibration():
    # Heading noise of the wheels from a per-step floor (0.017 rad per step).
    kw = {"k": (1e-3, 1e-6), "floor": [1e-8, 3e-4]}
    log, truth = simulate(27, steps=800, every=10, **kw)
    log = _with_gyro(log, truth, bias=0.02, sigma=0.01, seed=1)
    base = sim_config(**kw)
    sensors = dict(base.sensors, gyro={"sigma": 0.01, "calibrate": True, "bias_sigma": 0.05})
    res = ekf.run(log, dataclasses.replace(base, sensors=sensors))
    without = ekf.run(log, base)
    bias = res.extra["calibration"]["gyro_bias"]
    assert abs(bias["value"] - 0.02) < 3 * bias["sigma"] and bias["sigma"] < 0.005
    assert "gyro_theta_ref" not in res.extra["calibration"]
    # The first sample only sets the heading clone; the gate may reject a 3-sigma straggler.
    assert res.used["gyro"] + res.rejected["gyro"] == len(log.streams["gyro"]) - 1
    assert res.rejected["gyro"] <= 3
    assert _heading_rmse(res, truth) < 0.5 * _heading_rmse(without, truth)


def test_gyrodometry_switches_to_the_gyro_on_a_bump():
    log, truth = simulate(28, steps=300, k=(1e-4, 1e-6), every=1000)
    odo = log.streams["odometry"]
    values = odo.values.copy()
    values[100, 1] += 0.3  # a bump: the encoders report a 0.3 rad turn that never happened
    log = _stream(log, "odometry", odo.t, odo.columns, values)
    log = _with_gyro(log, truth, bias=0.0, sigma=0.002, seed=2)
    base = sim_config(k=(1e-4, 1e-6))
    plain = ekf.run(log, dataclasses.replace(base, sensors={}))
    sensors = {"gyro": {"sigma": 0.002, "gyrodometry": True, "threshold": 0.05}}
    res = ekf.run(log, dataclasses.replace(base, sensors=sensors))
    assert res.extra["gyrodometry_switches"] == 1
    assert abs(se2.wrap(plain.trajectory.poses[-1, 2] - truth[-1, 2])) > 0.25
    assert abs(se2.wrap(res.trajectory.poses[-1, 2] - truth[-1, 2])) < 0.02
    assert "gyro" not in res.used  # gyrodometry is part of the prediction, not an update


def test_config_errors_name_the_key():
    log, _ = simulate(29, steps=10)
    with pytest.raises(ConfigError) as info:
        ekf.run(log, _cfg(options={"late_windo": 1.0}))
    assert info.value.key == "options.ekf.late_windo" and info.value.file == "sim.yaml"
    with pytest.raises(ConfigError) as info:
        ekf.run(log, _cfg(options={"late_window": -1}))
    assert info.value.key == "options.ekf.late_window"
    cfg = dataclasses.replace(_cfg(), sensors={"gyro": {"sigma": 0.01, "gyrodometry": True}})
    with pytest.raises(ConfigError) as info:
        ekf.run(log, cfg)
    assert info.value.key == "sensors.gyro.threshold"


def test_odometry_going_back_in_time_is_an_input_error():
    log, _ = simulate(30, steps=10)
    loc, t, U = build(_cfg(), log, "ekf", ekf.make_backend)
    loc.add_odometry(t[1], U[0])
    with pytest.raises(ValueError, match="before the filter time"):
        loc.add_odometry(t[0], U[1])


def test_sensor_log_type_is_used_unchanged():
    log, _ = simulate(31, steps=5)
    assert isinstance(log, SensorLog)
    res = ekf.run(log, _cfg())
    assert res.trajectory.t[0] < log.streams["odometry"].t[0]
    np.testing.assert_allclose(res.trajectory.t[1:], log.streams["odometry"].t)


def test_bad_rows_are_input_errors_naming_stream_and_column():
    from odofuse.errors import InputError

    log, _ = simulate(32, steps=10)
    loc, t, U = build(_cfg(), log, "ekf", ekf.make_backend)
    with pytest.raises(InputError, match="ranges.*range"):
        loc.add_measurement("ranges", {"t": 1.0, "id": 0})
    with pytest.raises(InputError, match="non-finite"):
        loc.add_measurement("ranges", {"t": 1.0, "id": 0, "range": float("nan")})
    with pytest.raises(InputError, match="time"):
        loc.add_measurement("ranges", {"id": 0, "range": 3.0})
    with pytest.raises(InputError, match="non-finite"):
        loc.add_odometry(t[1], [0.1, float("inf")])
    # A stream without a model is an error (issue 16: a misspelled "GPS" was dropped silently).
    with pytest.raises(InputError, match="unknown stream 'sonar'"):
        loc.add_measurement("sonar", {"t": 1.0, "d": 3.0})
    loc.add_odometry(t[1], U[0])
    assert loc.t == t[1]


def test_live_localizer_from_config_without_a_log():
    from odofuse.estimators.localizer import Localizer

    log, _ = simulate(33, steps=120)
    cfg = _cfg()
    offline = ekf.run(log, cfg)
    _, t, U = build(cfg, log, "ekf", ekf.make_backend)
    loc = Localizer.from_config(
        cfg, t0=t[0], landmarks=log.landmarks, initial_pose=log.initial_pose
    )
    for te, kind, stream, i in events(log, t, U, ["ranges"]):
        if kind == 1:
            loc.add_odometry(te, U[i])
        else:
            loc.add(stream, log.streams[stream].row(i))
    np.testing.assert_array_equal(loc.pose(), offline.trajectory.poses[-1])
    np.testing.assert_array_equal(loc.covariance(), offline.trajectory.covariances[-1])
    with pytest.raises(ConfigError, match="streaming"):
        Localizer.from_config(cfg, t0=0.0, estimator="smoother")


def test_measurement_at_the_start_time_updates_the_initial_state():
    log, _ = simulate(34, steps=5)
    loc, t, U = build(_cfg(), log, "ekf", ekf.make_backend)
    P0 = loc.covariance()
    loc.add_measurement("ranges", {"t": t[0], "id": 0, "range": 19.0})
    assert loc.used["ranges"] == 1 and np.trace(loc.covariance()) < np.trace(P0)
    loc.add_measurement("ranges", {"t": t[0] - 5.0, "id": 0, "range": 19.0})
    assert loc.dropped_late["ranges"] == 1


def test_gyro_zero_order_hold_integral_and_late_gyro_samples():
    log, truth = simulate(35, steps=120, k=(1e-4, 1e-6), every=3)
    odo = log.streams["odometry"]
    values = odo.values.copy()
    values[50, 1] += 0.3  # a bump
    log = _stream(log, "odometry", odo.t, odo.columns, values)
    log = _with_gyro(log, truth, bias=0.0, sigma=0.002, seed=3)
    sensors = {
        "ranges": {"sigma": 0.3},
        "gyro": {"sigma": 0.002, "gyrodometry": True, "threshold": 0.05},
    }
    cfg = dataclasses.replace(_cfg(options={"late_window": 1.0}), sensors=sensors)
    loc, t, U = build(cfg, log, "ekf", ekf.make_backend)
    # Zero-order hold: rates 0.1 from t=0, 0.3 from t=1 -> 0.1 * 0.5 + 0.3 * 1.0 over (0.5, 2].
    loc._gyro = [(0.0, 0.1), (1.0, 0.3)]
    assert loc._gyro_increment(0.5, 2.0) == pytest.approx(0.35)
    assert loc._gyro_increment(-1.0, 0.0) == pytest.approx(0.1)  # first rate held backwards
    in_order, _ = _feed_online(log, cfg, "ekf")
    late, _ = _feed_online(log, cfg, "ekf", order=arrive_late("gyro", 0.25))
    a, b = in_order.result(), late.result()
    assert a.extra["gyrodometry_switches"] == b.extra["gyrodometry_switches"] == 1
    np.testing.assert_allclose(b.trajectory.poses, a.trajectory.poses, atol=1e-12)


def test_live_localizer_memory_is_flat_after_the_first_window(monkeypatch):
    # Issue 16: the Localizer kept its whole history (~330 bytes per step, never released).
    # A live Localizer keeps the late window's poses and its monitor's last readings only;
    # here the monitor keeps 50 readings, trimmed every 256 steps, so the steady state is
    # reached within the first 1,000 steps of a fix every other step.
    import tracemalloc

    import odofuse.estimators.localizer as localizer_module

    monkeypatch.setattr(localizer_module, "_KEEP_READINGS", 50)
    monkeypatch.setattr(localizer_module, "_TRIM_EVERY", 256)
    cfg = _live_gps_config(late_window=0.5, nis_window=10)
    loc = localizer_module.Localizer.from_config(cfg, 0.0)
    u = np.array([0.02, 0.0])  # 0.2 m/s along x
    noise = np.random.default_rng(5).normal(0.0, 0.5, 4001).tolist()
    used = {}

    def run(k0, k1):
        for k in range(k0, k1):
            t = 0.1 * k
            loc.add_odometry(t, u)
            if k % 2 == 0:  # every other fix 0.25 s late: buffered or replayed
                late = 0.25 if k % 4 == 0 else -0.05
                fix = {"t": t - late, "x": 0.2 * (t - late) + noise[k], "y": 0.0}
                out = loc.add_measurement("gps", fix)
                used[out] = used.get(out, 0) + 1

    run(1, 1000)
    tracemalloc.start()
    try:
        run(1000, 2000)
        first = tracemalloc.get_traced_memory()[0]
        run(2000, 4000)
        second = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    # 2,000 more steps and 1,000 more fixes: the old history would add ~660 kB here.
    assert second - first < 4096, (first, second)
    assert used == {"used": 999, "buffered": 1000}  # the late ones replayed at once
    assert loc.used["gps"] >= 1998 and loc.rejected["gps"] == 0
    assert len(loc.trajectory()) <= 512 and len(loc._steps) <= 7
    assert all(len(a) <= 50 + 256 for a in loc.monitor._t.values())
    loc.health()  # the windowed findings still work


def test_live_ekf_equals_odofuse_run_bit_for_bit_with_the_compiled_core():
    # Issue 16: `odofuse run`'s EKF uses the compiled core by default, which matched the
    # Python streaming path to 1e-9 only. A live EKF Localizer now runs the same step kernels
    # (compiled.ekf.live), so online == offline bit for bit: odometry at 50 Hz, a GPS fix each
    # second arriving 0.3 s late (a replay of 15 steps each time).
    from odofuse.estimators.compiled import load_kernels
    from odofuse.estimators.localizer import Localizer
    from odofuse.motion import motion_model_from_config

    if load_kernels() is None:
        pytest.skip("numba not importable")
    cfg = _live_gps_config()
    rng = np.random.default_rng(16)
    n, dt = 3000, 0.02
    t = dt * np.arange(1, n + 1)
    U = np.column_stack([0.01 + rng.normal(0, 1e-3, n), 0.001 + rng.normal(0, 1e-4, n)])
    truth, _ = dead_reckon(motion_model_from_config(cfg), np.zeros(3), None, U, with_cov=False)
    k = np.arange(49, n, 50)  # the fix taken 0.3 s before step k's end, sent with step k
    tg = t[k] - 0.3
    xy = np.interp(tg, np.r_[0.0, t], truth[:, 0]), np.interp(tg, np.r_[0.0, t], truth[:, 1])
    gps = np.column_stack(xy) + rng.normal(0.0, 0.5, (len(k), 2))
    log = SensorLog(
        "sim",
        {
            "odometry": Stream("odometry", "sim", t, ("ds", "dtheta"), U),
            "gps": Stream("gps", "sim", tg, ("x", "y"), gps),
        },
        initial_pose=np.zeros(3),
    )
    offline = ekf.run(log, cfg)  # the compiled core (options.ekf.compiled: auto)
    _, t_all, U_all = build(cfg, log, "ekf", ekf.make_backend)
    loc = Localizer.from_config(cfg, t0=t_all[0])
    assert type(loc.backend).__name__ == "KernelEkfBackend"
    fixes = dict(zip(k.tolist(), range(len(k)), strict=True))
    outcomes = []
    for i in range(n):
        loc.add_odometry(t_all[i + 1], U_all[i])
        if i in fixes:
            j = fixes[i]
            fix = {"t": tg[j], "x": gps[j, 0], "y": gps[j, 1]}
            outcomes.append(loc.add_measurement("gps", fix))
    assert set(outcomes) == {"used"}  # every late fix replayed at once
    online = loc.result()
    m = len(online.trajectory.t)  # a live Localizer keeps the late window's poses
    np.testing.assert_array_equal(online.trajectory.t, offline.trajectory.t[-m:])
    np.testing.assert_array_equal(online.trajectory.poses, offline.trajectory.poses[-m:])
    np.testing.assert_array_equal(
        online.trajectory.covariances, offline.trajectory.covariances[-m:]
    )
    assert online.used == offline.used == {"gps": len(k)}
    assert online.extra["map_to_odom"] == offline.extra["map_to_odom"]
    x_off = offline.trajectory.poses[-1]
    np.testing.assert_array_equal(loc.pose(), x_off)
    # `compiled: off` keeps the Python backend, equal to the offline Python path bit for bit
    # (test_streaming_equals_the_offline_run); the two paths agree to 1e-9.
    off = dataclasses.replace(cfg, options={"ekf": {"compiled": "off"}})
    assert type(Localizer.from_config(off, t0=t_all[0]).backend) is ekf.EkfBackend
    python = ekf.run(log, off)
    np.testing.assert_allclose(python.trajectory.poses, offline.trajectory.poses, atol=1e-9)


def test_a_burst_of_late_readings_costs_one_window_each(monkeypatch):
    # Issue 16: late bursts cost O(n^2) (1,000 late rows 13 s): each replay walked the whole
    # history. Now the Localizer keeps the late window's steps only and a late reading replays
    # the steps after it, at most one window. Counted in steps, not timed: 300 readings in
    # the last 0.45 s (each replay re-applies the window's earlier readings, so the applies
    # grow with the square of a burst that dense; the steps a reading replays do not).
    from odofuse.estimators.localizer import Localizer

    cfg = _live_gps_config(late_window=0.5)
    loc = Localizer.from_config(cfg, 0.0)
    u = np.array([0.02, 0.0])
    for k in range(1, 2001):  # 200 s of history at 10 Hz
        loc.add_odometry(0.1 * k, u)
    calls = []
    real = Localizer._process_step
    monkeypatch.setattr(
        Localizer, "_process_step", lambda self, *a: (calls.append(1), real(self, *a))[1]
    )
    rng = np.random.default_rng(8)
    late = loc.t - rng.uniform(0.0, 0.45, 300)
    outcomes = {loc.add_measurement("gps", {"t": tm, "x": 0.2 * tm, "y": 0.0}) for tm in late}
    assert outcomes == {"used"}
    window_steps = int(math.ceil(loc.late_window / 0.1)) + 1
    assert len(loc._steps) <= window_steps
    assert len(calls) <= 300 * window_steps  # the whole history: 2,000 steps a reading
    assert loc.used["gps"] == 300


def test_live_compiled_ekf_recovers_as_the_python_one():
    # The kernel backend reads a recovery's innovation from the model (last_innovation) and
    # re-applies the reading through the kernel: the same recoveries as the Python backend,
    # poses to 1e-9. GPS fixes 20 m off from the start: rejected until the filter re-opens.
    from odofuse.estimators.compiled import load_kernels
    from odofuse.estimators.localizer import Localizer

    if load_kernels() is None:
        pytest.skip("numba not importable")

    def run(compiled):
        cfg = _live_gps_config(compiled=compiled)
        loc = Localizer.from_config(cfg, 0.0)
        rng = np.random.default_rng(4)
        for k in range(1, 601):
            loc.add_odometry(0.1 * k, np.array([0.02, 0.0]))
            if k % 5 == 0:
                x, y = 0.02 * k + 20.0 + rng.normal(0, 0.5), rng.normal(0, 0.5)
                loc.add_measurement("gps", {"t": 0.1 * k - 0.05, "x": x, "y": y})
        return loc

    kern, py = run("auto"), run("off")
    assert type(kern.backend).__name__ == "KernelEkfBackend"
    assert type(py.backend) is ekf.EkfBackend
    assert len(kern.monitor.recoveries) == len(py.monitor.recoveries) > 0
    assert kern.used == py.used and kern.rejected == py.rejected
    np.testing.assert_allclose(kern.pose(), py.pose(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(kern.covariance(), py.covariance(), rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("odometry_calibration", [True, False])
def test_live_ekf_with_calibration_states_equals_odofuse_run_bit_for_bit(odometry_calibration):
    # The same with ranges and their scale/offset states, with and without the
    # odometry-calibration states (the kernels' general-matrix prediction).
    from odofuse.estimators.compiled import load_kernels
    from odofuse.estimators.localizer import Localizer

    if load_kernels() is None:
        pytest.skip("numba not importable")
    log, _ = simulate(7, steps=600)
    opts = {"odometry_calibration": True} if odometry_calibration else {}
    cfg = sim_config(estimator="ekf", calibrate=True, **opts)
    offline = ekf.run(log, cfg)
    _, t, U = build(cfg, log, "ekf", ekf.make_backend)
    loc = Localizer.from_config(
        cfg, t0=t[0], landmarks=log.landmarks, initial_pose=log.initial_pose, keep_trajectory=True
    )
    assert type(loc.backend).__name__ == "KernelEkfBackend"
    for te, kind, stream, i in events(log, t, U, ["ranges"]):
        if kind == 1:
            loc.add_odometry(te, U[i])
        else:
            loc.add(stream, log.streams[stream].row(i))
    loc.finish()
    online = loc.result()
    np.testing.assert_array_equal(online.trajectory.poses, offline.trajectory.poses)
    np.testing.assert_array_equal(online.trajectory.covariances, offline.trajectory.covariances)
    assert online.used == offline.used and online.rejected == offline.rejected
    assert online.extra["calibration"] == offline.extra["calibration"]
    assert online.extra["map_to_odom"] == offline.extra["map_to_odom"]
