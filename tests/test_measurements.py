"""Measurement models: reference values, analytic Jacobians, residuals, config, GTSAM factors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.config import RunConfig
from odofuse.errors import ConfigError
from odofuse.measurements import (
    BeaconRange,
    CompassHeading,
    GpsPosition,
    GyroYawRate,
    LandmarkBearing,
    LandmarkRangeBearing,
    gate_threshold,
    measurement_models,
)
from odofuse.testing import numerical_jacobian

LM = {1: np.array([3.0, 4.0]), 7: np.array([-10.0, 2.5])}


def _bound(model):
    return model.bind({s: 3 + i for i, s in enumerate(model.calib_states)})


CASES = [
    (GpsPosition("gps", 1.5, lever_arm=(0.3, -0.1)), {"t": 0.0, "x": 1.0, "y": 2.0}, 0),
    (CompassHeading("compass", 0.05, calibrate=True), {"t": 0.0, "heading": 3.0}, 1),
    (GyroYawRate("gyro", 0.01, calibrate=True), {"t": 0.0, "wz": 0.1, "dt": 0.1}, 2),
    (
        BeaconRange("ranges", 0.3, landmarks=LM, calibrate=True),
        {"t": 0.0, "id": 1, "range": 5.0},
        2,
    ),
    (BeaconRange("ranges", 0.3, landmarks=LM), {"t": 0.0, "id": 7, "range": 5.0}, 0),
    (LandmarkBearing("bearings", 0.02, landmarks=LM), {"t": 0.0, "id": 7, "bearing": 0.1}, 0),
    (
        LandmarkRangeBearing("landmarks", 0.2, landmarks=LM),
        {"t": 0.0, "id": 1, "range": 5.0, "bearing": 0.1},
        0,
    ),
]
STATES = [
    np.array([0.5, -0.2, 0.3, 1.05, 0.2]),
    np.array([-2.0, 7.0, math.pi - 1e-7, 0.97, -0.3]),
    np.array([1.0, 1.0, -math.pi + 1e-7, 1.0, 0.0]),
]


@pytest.mark.parametrize("model,row,n_aug", CASES, ids=lambda c: getattr(c, "name", ""))
@pytest.mark.parametrize("x", STATES)
def test_jacobians_match_central_differences(model, row, n_aug, x):
    m = _bound(model)
    x = x[: 3 + n_aug]
    H = m.H(x, row)
    assert H.shape == (m.dim, x.size)
    H_num = numerical_jacobian(lambda v: m.h(v, row), x, wrap_rows=m.angle_rows)
    np.testing.assert_allclose(H, H_num, atol=1e-7)


def test_range_reference_values_and_calibration():
    m = BeaconRange("ranges", 0.3, landmarks=LM)
    assert m.h(np.zeros(3), {"id": 1})[0] == pytest.approx(5.0)  # 3-4-5 triangle
    cal = _bound(BeaconRange("ranges", 0.3, landmarks=LM, calibrate=True))
    assert cal.calib_states == ("range_scale", "range_offset")
    x = np.array([0.0, 0.0, 0.0, 1.04, 0.25])
    assert cal.h(x, {"id": 1})[0] == pytest.approx(1.04 * 5.0 + 0.25)
    # H w.r.t. the scale is the geometric distance, w.r.t. the offset is one.
    np.testing.assert_allclose(cal.H(x, {"id": 1})[0, 3:], [5.0, 1.0])
    # An unbound calibrating model uses the nominal scale/offset on a bare pose.
    assert BeaconRange("r", landmarks=LM, calibrate=True).h(np.zeros(3), {"id": 1})[0] == 5.0


def test_unknown_beacon_names_the_stream_and_id():
    with pytest.raises(ValueError, match=r"ranges.*landmark id 3"):
        BeaconRange("ranges", landmarks=LM).h(np.zeros(3), {"t": 1.0, "id": 3, "range": 1.0})


def test_bearing_and_range_bearing_reference_values():
    b = LandmarkBearing("bearings", landmarks={0: np.array([1.0, 1.0])})
    assert b.h(np.zeros(3), {"id": 0})[0] == pytest.approx(math.pi / 4)
    # Robot at the origin facing +y: the landmark at 45 deg is 45 deg to the right.
    assert b.h(np.array([0.0, 0.0, math.pi / 2]), {"id": 0})[0] == pytest.approx(-math.pi / 4)
    # Behind the robot the bearing wraps to [-pi, pi).
    behind = b.h(np.array([2.0, 1.0 + 1e-9, 0.0]), {"id": 0})[0]
    assert -math.pi <= behind < math.pi and abs(abs(behind) - math.pi) < 1e-6
    rb = LandmarkRangeBearing("landmarks", 0.2, landmarks={0: np.array([1.0, 1.0])})
    np.testing.assert_allclose(rb.h(np.zeros(3), {"id": 0}), [math.sqrt(2), math.pi / 4])
    np.testing.assert_allclose(rb.R({}), np.diag([0.04, 0.02**2]))


def test_gps_lever_arm_rotates_with_the_heading():
    m = GpsPosition("gps", 1.0, lever_arm=(0.5, 0.2))
    np.testing.assert_allclose(m.h(np.array([1.0, 2.0, 0.0])), [1.5, 2.2])
    # Facing +y the forward arm points north and the left arm points west.
    np.testing.assert_allclose(m.h(np.array([1.0, 2.0, math.pi / 2])), [0.8, 2.5], atol=1e-12)
    assert m.R({"sigma": 3.0})[0, 0] == 9.0  # per-fix sigma column overrides
    assert m.R({})[1, 1] == 1.0


def test_gps_latlon_converted_about_the_datum():
    m = GpsPosition("gps", 1.0, datum=(48.0, 11.0, 500.0))
    np.testing.assert_allclose(m.z({"lat": 48.0, "lon": 11.0}), [0.0, 0.0], atol=1e-6)
    north = m.z({"lat": 48.001, "lon": 11.0})
    # One millidegree of latitude at 48 deg is ~111.2 m of meridian arc (WGS-84).
    assert abs(north[0]) < 1e-3 and north[1] == pytest.approx(111.2, abs=0.3)
    east = m.z({"lat": 48.0, "lon": 11.001})
    assert east[0] == pytest.approx(111.32 * math.cos(math.radians(48.0)), abs=0.3)
    with pytest.raises(ValueError, match="datum"):
        GpsPosition("gps").z({"lat": 48.0, "lon": 11.0})


def test_latlon_gps_without_datum_uses_its_first_fix():
    from odofuse.io.log import SensorLog, Stream

    fixes = Stream("gps", "gps.csv", [0.0, 1.0], ("lat", "lon"), [[48.0, 11.0], [48.001, 11.0]])
    log = SensorLog("mem", {"gps": fixes})
    model = measurement_models(_config({"gps": {"sigma": 2.0}}), log)["gps"]
    assert model.datum == (48.0, 11.0)
    np.testing.assert_allclose(model.z(fixes.row(0)), [0.0, 0.0], atol=1e-9)
    assert model.z(fixes.row(1))[1] == pytest.approx(111.2, abs=0.3)
    # an explicit datum is kept
    kept = measurement_models(_config({"gps": {"sigma": 2.0, "datum": [47.9, 11.0]}}), log)
    assert kept["gps"].datum == (47.9, 11.0)


def test_residual_wraps_angles_only():
    c = CompassHeading("compass")
    np.testing.assert_allclose(c.residual([math.pi - 0.01], [-math.pi + 0.01]), [-0.02], atol=1e-12)
    rb = LandmarkRangeBearing("landmarks", landmarks=LM)
    np.testing.assert_allclose(rb.residual([10.0, 3.1], [2.0, -3.1]), [8.0, 6.2 - 2 * math.pi])
    r = BeaconRange("ranges", landmarks=LM)
    np.testing.assert_allclose(r.residual([10.0], [2.0]), [8.0])
    # Circular mean of angles either side of pi stays near pi.
    mean = c.mean(np.array([[math.pi - 0.1], [-math.pi + 0.1]]), np.array([0.5, 0.5]))
    assert abs(abs(mean[0]) - math.pi) < 1e-12


def test_gyro_rate_against_the_cloned_heading():
    g = _bound(GyroYawRate("gyro", 0.01, calibrate=True))
    assert g.calib_states == ("gyro_theta_ref", "gyro_bias")
    assert g.clones() == {"gyro_theta_ref": 2}
    x = np.array([0.0, 0.0, -math.pi + 0.05, math.pi - 0.05, 0.002])
    # The heading moved by +0.1 rad across +-pi in 0.5 s: 0.2 rad/s plus the bias.
    assert g.h(x, {"dt": 0.5})[0] == pytest.approx(0.2 + 0.002)
    with pytest.raises(ValueError, match="dt"):
        g.h(x, {"wz": 0.1})


def test_gate_threshold_is_the_chi_square_quantile():
    assert gate_threshold(0.95, 1) == pytest.approx(3.841458820694124)
    assert gate_threshold(0.99, 2) == pytest.approx(9.210340371976182)
    assert gate_threshold(None, 2) == math.inf


# --------------------------------------------------------------------------- config
class _Log:
    landmarks = LM


def _config(sensors):
    return RunConfig(log="x", robot={"drive": "increments"}, sensors=sensors, source="run.yaml")


def test_factory_builds_models_from_the_sensor_blocks():
    models = measurement_models(
        _config(
            {
                "ranges": {"sigma": 0.7, "gate": 0.99, "calibrate": True},
                "gps": {"sigma": 2.0, "lever_arm": [0.1, 0.0], "datum": [48.0, 11.0]},
                "compass": {"sigma": 0.05},
                "gyro": {"sigma": 0.01, "calibrate": True, "gyrodometry": True, "threshold": 0.01},
                "landmarks": {"sigma_range": 0.2, "sigma_bearing": 0.02},
                "my_bearings": {"model": "bearing", "sigma": 0.03},
            }
        ),
        _Log(),
    )
    assert isinstance(models["ranges"], BeaconRange) and models["ranges"].calibrate
    assert models["ranges"].gate == 0.99 and models["ranges"].sigma == 0.7
    assert models["gps"].lever_arm == (0.1, 0.0) and models["gps"].datum == (48.0, 11.0)
    assert models["compass"].gate == 0.999
    assert isinstance(models["gyro"], GyroYawRate) and models["gyro"].calibrate
    assert isinstance(models["landmarks"], LandmarkRangeBearing)
    assert models["landmarks"].sigma_bearing == 0.02
    assert isinstance(models["my_bearings"], LandmarkBearing)
    assert models["my_bearings"].h(np.zeros(3), {"id": 1})[0] == pytest.approx(math.atan2(4, 3))


def test_user_model_by_class_path():
    models = measurement_models(
        _config({"heading": {"class": "odofuse.measurements:CompassHeading", "sigma": 0.1}}),
        _Log(),
    )
    assert isinstance(models["heading"], CompassHeading) and models["heading"].name == "heading"


@pytest.mark.parametrize(
    "sensors,key",
    [
        ({"ranges": {"sigma": 0.3, "sigmaa": 1}}, "sensors.ranges.sigmaa"),
        ({"ranges": {"sigma": -1}}, "sensors.ranges.sigma"),
        ({"ranges": {"gate": 1.5}}, "sensors.ranges.gate"),
        ({"ranges": {"calibrate": "yes"}}, "sensors.ranges.calibrate"),
        ({"gps": {"lever_arm": [1, 2, 3]}}, "sensors.gps.lever_arm"),
        ({"sonar": {"sigma": 1}}, "sensors.sonar.model"),
        ({"ranges": {"class": "nowhere.module:Nope"}}, "sensors.ranges.class"),
        (
            {"ranges": {"class": "odofuse.measurements:CompassHeading", "bogus": 1}},
            "sensors.ranges.class",
        ),
    ],
)
def test_config_errors_name_the_key_and_file(sensors, key):
    with pytest.raises(ConfigError) as info:
        measurement_models(_config(sensors), _Log())
    assert info.value.key == key and info.value.file == "run.yaml"
    assert "run.yaml" in str(info.value)


def test_range_sensor_without_a_map_is_a_config_error():
    class NoMap:
        landmarks = {}

    with pytest.raises(ConfigError, match="map"):
        measurement_models(_config({"ranges": {"sigma": 0.3}}), NoMap())


# --------------------------------------------------------------------------- GTSAM
gtsam = pytest.importorskip("gtsam")


def _values(pose, scalars=()):
    v = gtsam.Values()
    v.insert(0, gtsam.Pose2(*pose))
    for i, s in enumerate(scalars):
        v.insert(100 + i, np.array([s]))
    return v


def _whitened(model, row, x):
    L = np.linalg.cholesky(np.linalg.inv(model.R(row)))
    return L.T @ (-model.residual(model.z(row), model.h(x, row)))


@pytest.mark.parametrize(
    "model,row,n_aug", CASES[:2] + CASES[3:], ids=lambda c: getattr(c, "name", "")
)
def test_custom_factor_error_and_jacobian(model, row, n_aug):
    names = model.calib_states[:n_aug]
    calib_keys = {s: 100 + i for i, s in enumerate(names)}
    x = STATES[0][: 3 + n_aug]
    f = model.factor(0, row, calib_keys=calib_keys)
    v = _values(x[:3], x[3:])
    b = _bound(model) if n_aug else model
    # 0.5 |whitened error|^2 is GTSAM's factor error.
    assert f.error(v) == pytest.approx(0.5 * np.sum(_whitened(b, row, x) ** 2), rel=1e-9)
    # Jacobian of the whitened error w.r.t. the Pose2 body tangent, by central differences.
    A, _ = f.linearize(v).jacobian()
    A = np.asarray(A)[:, :3]

    def err(xi):
        p = gtsam.Pose2(*x[:3]).retract(xi)
        return _whitened(b, row, np.r_[p.x(), p.y(), p.theta(), x[3:]])

    np.testing.assert_allclose(A, numerical_jacobian(err, np.zeros(3)), atol=1e-6)


def test_builtin_factors_match_the_model():
    x = np.array([0.5, -0.2, 0.3])
    v = _values(x)
    gps = GpsPosition("gps", 1.5)
    row = {"x": 1.0, "y": 2.0}
    f = gps.factor(0, row)
    assert isinstance(f, gtsam.PoseTranslationPrior2D)
    assert f.error(v) == pytest.approx(0.5 * np.sum(_whitened(gps, row, x) ** 2))
    comp = CompassHeading("compass", 0.05)
    row = {"heading": 3.0}
    f = comp.factor(0, row)
    assert isinstance(f, gtsam.PoseRotationPrior2D)
    assert f.error(v) == pytest.approx(0.5 * np.sum(_whitened(comp, row, x) ** 2))
    rng_model = BeaconRange("ranges", 0.3, landmarks=LM)
    row = {"id": 1, "range": 5.5}
    v.insert(50, gtsam.Point2(*LM[1]))
    f = rng_model.factor(0, row, landmark_key=50)
    assert isinstance(f, gtsam.RangeFactor2D)
    assert f.error(v) == pytest.approx(0.5 * np.sum(_whitened(rng_model, row, x) ** 2))
    rb = LandmarkRangeBearing("landmarks", 0.2, landmarks=LM)
    row = {"id": 1, "range": 5.5, "bearing": 0.8}
    f = rb.factor(0, row, landmark_key=50)
    assert f.error(v) == pytest.approx(0.5 * np.sum(_whitened(rb, row, x) ** 2))


def test_gyro_factor_between_two_poses():
    g = GyroYawRate("gyro", 0.01)
    f = g.factor((0, 1), {"wz": 0.2, "dt": 0.5})
    v = gtsam.Values()
    v.insert(0, gtsam.Pose2(0.0, 0.0, math.pi - 0.05))
    v.insert(1, gtsam.Pose2(0.1, 0.0, -math.pi + 0.05))
    # Heading change +0.1 rad against 0.2 rad/s * 0.5 s: zero error.
    assert f.error(v) == pytest.approx(0.0, abs=1e-20)
    v.update(1, gtsam.Pose2(0.1, 0.0, -math.pi + 0.06))
    assert f.error(v) == pytest.approx(0.5 * (0.01 / (0.01 * 0.5)) ** 2)


@pytest.mark.parametrize("model,row,n_aug", CASES, ids=lambda c: getattr(c, "name", ""))
def test_vectorised_h_equals_h_row_by_row(model, row, n_aug):
    m = _bound(model)
    rng = np.random.default_rng(4)
    X = rng.normal(0.0, 2.0, (25, 3 + n_aug))
    X[:, 2] = rng.uniform(-math.pi, math.pi, 25)
    X[:, 3:] = rng.normal(0.0, 0.1, (25, n_aug)) + (1.0 if n_aug else 0.0)
    expected = np.array([m.h(x, row) for x in X])
    np.testing.assert_allclose(m.h_many(X, row), expected, rtol=1e-13, atol=1e-13)
