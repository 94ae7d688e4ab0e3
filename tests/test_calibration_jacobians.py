"""Odometry calibration of two-sided drives with 1, 2 or 3 wheels a side (issues 10 and 11).

The calibration parameters mean a change of the drive's geometry (``E_d``: right / left radius
ratio with the mean kept; ``E_b``: the track, for the skid steer the ICR coordinates
``y_l, y_r``, scaled; ``E_s``: both radii scaled, UMBmark's scale error). Checked against
central differences of the drive model with that geometry perturbed, for every two-sided drive
of the calibration table and ``wheels_per_side`` 1, 2, 3, with unequal radii and offset ICRs:

* the graph's input Jacobian ``D`` (``F0 D = d twist / dp``),
* the graph's preintegrated pose-increment sensitivity ``G`` (``preintegrate``),
* the filters' calibrated input ``u' = f(u, p)``: exactly the perturbed drive's twist, and its
  Jacobian against central differences.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from odofuse import se2
from odofuse.drives import make_drive
from odofuse.estimators.graph.calibration import _ODO_CAL, odometry_calibration_for
from odofuse.estimators.graph.keyframes import preintegrate
from odofuse.estimators.odocal import FilterOdometryCalibration
from odofuse.motion import MotionModel, error_model_from_config
from odofuse.testing import numerical_jacobian

GEOMETRIES = {
    "differential": [
        {"wheel_radius": 0.1, "track_width": 0.5},
        {"wheel_radius": 0.1, "track_width": 0.5, "wheel_radius_right": 0.104},
    ],
    "skid_steer": [
        {"wheel_radius": 0.12, "track_width": 0.6},
        {"wheel_radius": 0.12, "track_width": 0.6, "y_l": 0.41, "y_r": -0.33, "x_G": 0.07},
        {
            "wheel_radius": 0.12,
            "track_width": 0.6,
            "y_l": 0.38,
            "y_r": -0.36,
            "wheel_radius_left": 0.118,
        },
    ],
}
CASES = [
    (drive, geometry, n)
    for drive in _ODO_CAL
    if drive != "increments"
    for geometry in GEOMETRIES[drive]
    for n in (1, 2, 3)
]


def _perturbed(drive, p):
    """``drive`` with the geometry that the calibration parameters ``p = (E_d, E_b[, E_s])``
    mean."""
    E, Eb = p[0], p[1]
    Es = p[2] if len(p) > 2 else 1.0
    g = {
        "wheel_radius_left": drive.wheel_radius_left * Es * 2.0 / (1.0 + E),
        "wheel_radius_right": drive.wheel_radius_right * Es * 2.0 * E / (1.0 + E),
        "track_width": drive.track_width * Eb,
    }
    if drive.name == "skid_steer":
        g.update(y_l=drive.y_l * Eb, y_r=drive.y_r * Eb)
    return dataclasses.replace(drive, **g)


def _setup(name, geometry, n):
    drive = make_drive(name, **geometry, wheels_per_side=n)
    model = MotionModel(drive, error_model_from_config(drive, {"k": 1e-4}))
    return drive, model, odometry_calibration_for(model, True, "k", "test.yaml")


def _inputs(rng, n, rows):
    """Wheel angle increments ``(rows, 2n)``: a turning forward motion, wheels of a side
    disagreeing a little (so a left/right mix-up cannot pass)."""
    left = rng.uniform(0.5, 1.5, (rows, 1)) + rng.normal(0.0, 0.2, (rows, n))
    right = left.mean(1, keepdims=True) + rng.uniform(-0.6, 0.6, (rows, 1))
    return np.hstack([left, right + rng.normal(0.0, 0.2, (rows, n))])


@pytest.mark.parametrize("name, geometry, n", CASES)
def test_input_jacobian_is_the_perturbed_drives_twist(name, geometry, n):
    drive, _, cal = _setup(name, geometry, n)
    assert cal.wheels_per_side == n
    rng = np.random.default_rng(7)
    u = _inputs(rng, n, 5)
    D = cal.input_jacobian(u, np.full(len(u), 0.1))
    assert D.shape == (5, 2 * n, 3) and cal.names[2] == "wheel_radius_scale"
    for row, Dk in zip(u, D, strict=True):
        num = numerical_jacobian(lambda p, row=row: _perturbed(drive, p).twist(row), cal.nominal)
        np.testing.assert_allclose(drive.J_twist_u(row) @ Dk, num, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("name, geometry, n", CASES)
def test_preintegrated_sensitivity_matches_central_differences(name, geometry, n):
    drive, model, cal = _setup(name, geometry, n)
    rng = np.random.default_rng(11)
    steps = 40
    t = np.arange(steps + 1) * 0.1
    U = 0.1 * _inputs(rng, n, steps)
    kt = np.array([0.0, 0.73, 1.9, 4.0])  # keyframes cutting steps
    deltas, _, G = preintegrate(t, U, model, kt, cal)

    def tangent(p, i):
        m = dataclasses.replace(model, drive=_perturbed(drive, p))
        xi = se2.log(se2.between(deltas[i], preintegrate(t, U, m, kt)[0][i]))
        return xi[[1, 2, 0]]  # (omega, v_x, v_y) -> GTSAM's Pose2 tangent (x, y, theta)

    for i in range(len(kt) - 1):
        num = numerical_jacobian(lambda p, i=i: tangent(p, i), np.array(cal.nominal))
        np.testing.assert_allclose(G[i], num, rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize("name, geometry, n", CASES)
def test_filter_calibrated_input_is_the_perturbed_drive(name, geometry, n):
    drive, _, base = _setup(name, geometry, n)
    cal = FilterOdometryCalibration(
        base.drive, base.names, base.nominal, base.sigma, (0.0, 0.0, 0.0), (), n, base.track
    )
    rng = np.random.default_rng(3)
    u = _inputs(rng, n, 4)
    for p in ([1.0, 1.0, 1.0], [1.03, 0.96, 1.02], [0.95, 1.07, 0.97]):
        p = np.array(p)
        np.testing.assert_allclose(
            drive.twist(cal.apply(u, p, 0.1)), _perturbed(drive, p).twist(u), atol=1e-12
        )
        # batched parameters (the particle filter: one p per row)
        P = np.tile(p, (len(u), 1))
        np.testing.assert_allclose(cal.apply(u, P, 0.1), cal.apply(u, p, 0.1), atol=1e-15)
        for row in u:
            num = numerical_jacobian(lambda q, row=row: cal.apply(row, q, 0.1), p)
            np.testing.assert_allclose(cal.jacobian(row, p, 0.1), num, rtol=1e-7, atol=1e-9)
    nominal = np.array(base.nominal)
    for row in u:  # the filters' Jacobian at the nominal values is the graph's
        np.testing.assert_allclose(
            cal.jacobian(row, nominal, 0.1), base.input_jacobian(row[None], [0.1])[0], atol=1e-14
        )


def test_one_symmetric_wheel_a_side_keeps_borensteins_half_difference():
    """Equal radii, ``y_l = -y_r``: ``D`` is the half difference ``h = (R - L)/2`` as before
    (and the scale's column the inputs themselves)."""
    for name, geometry in (("differential", GEOMETRIES["differential"][0]),) + (
        ("skid_steer", GEOMETRIES["skid_steer"][0]),
    ):
        _, _, cal = _setup(name, geometry, 1)
        u = np.array([[1.3, 2.1]])
        D = cal.input_jacobian(u, [0.1])[0]
        np.testing.assert_allclose(D, [[-0.65, 0.4, 1.3], [1.05, -0.4, 2.1]], atol=1e-14)


@pytest.mark.parametrize(
    "robot, covered",
    [
        ({"wheel_radius": 0.1, "track_width": 0.5}, True),
        ({"wheel_radius": 0.1, "track_width": 0.5, "wheel_radius_right": 0.102}, False),
    ],
)
def test_compiled_ekf_covers_only_the_symmetric_calibration(robot, covered):
    """The kernel's calibrated input is Borenstein's half difference of inputs 0 and 1: other
    geometries take the Python path (which is the perturbed drive, tested above)."""
    pytest.importorskip("numba")
    from graph_sim import simulated_run

    from odofuse.estimators.compiled import ekf as compiled_ekf

    scenario = {
        "seed": 1,
        "dt": 0.05,
        "robot": {"drive": "differential", **robot},
        "path": {"kind": "figure_eight", "radius": 3.0, "speed": 0.4, "laps": 1},
        "nonsystematic": {"k": 1.0e-5},
        "sensors": {"ranges": {"sigma": 0.1, "rate": 1.0, "max_range": 15.0}},
        "beacons": [[1, 0.0, 6.0], [2, 0.0, -6.0], [3, 8.0, 0.0]],
    }
    options = {"odometry_calibration": True, "slip": False, "compiled": "on"}
    log, cfg = simulated_run(scenario, 1, "ekf", options)
    assert (compiled_ekf.run(log, cfg) is not None) is covered


def test_two_prior_sigmas_calibrate_e_d_and_e_b_alone():
    """A config's two sigmas keep the two-parameter calibration (the scale taken as exact)."""
    drive = make_drive("differential", wheel_radius=0.1, track_width=0.5)
    model = MotionModel(drive, error_model_from_config(drive, {"k": 1e-4}))
    cal = odometry_calibration_for(model, [0.02, 0.03], "k", "test.yaml")
    assert cal.names == ("wheel_radius_ratio", "track_width_scale") and cal.sigma == (0.02, 0.03)
    assert cal.input_jacobian(np.array([[1.3, 2.1]]), [0.1]).shape == (1, 2, 2)
    with pytest.raises(Exception, match="3 prior sigmas"):
        odometry_calibration_for(model, [0.02], "k", "test.yaml")
