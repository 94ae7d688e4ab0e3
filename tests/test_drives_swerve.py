"""Swerve drive: Jacobians, inverse kinematics and WPILib's wpimath test cases.

Peer values come from wpilibsuite/allwpilib (commit caf0fb2d), files
``wpimath/src/test/native/cpp/kinematics/SwerveDriveKinematicsTest.cpp``,
``SwerveDriveOdometryTest.cpp`` and ``SwerveModuleVelocityTest.cpp``. Conventions: wpimath
module positions are ``Translation2d(x forward, y left)`` in metres, the same as our
``modules``; module angles are ``Rotation2d``, counter-clockwise from +x, as our ``s_i``;
module speeds (m/s) and positions (m) map to our wheel increments with ``wheel_radius = 1``.
wpimath's tolerance there is 0.1 (0.01 for odometry); we use theirs on their rounded
numbers and 1e-12 where the value is exact.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.drives import Swerve, desaturate, make_drive, optimize_angles
from odofuse.motion import body_increment
from odofuse.se2 import wrap
from odofuse.testing import numerical_jacobian

DEG = math.pi / 180.0
# wpimath's SwerveDriveKinematicsTest fixture: fl, fr, bl, br at (+-12, +-12) m.
WPI = Swerve(1.0, [[12.0, 12.0], [12.0, -12.0], [-12.0, 12.0], [-12.0, -12.0]])


def _modules(speeds, angles_deg):
    return np.r_[speeds, np.asarray(angles_deg) * DEG]


def _twist_about(omega, vx, vy, centre):
    """Body-origin twist of a motion given about ``centre`` (wpimath's centerOfRotation)."""
    cx, cy = centre
    return np.array([omega, vx + omega * cy, vy - omega * cx])


# --------------------------------------------------------------------------- wpimath kinematics
def test_wpimath_straight_line_and_strafe():
    # SwerveDriveKinematicsTest: StraightLineInverseKinematics / ForwardKinematics(WithDeltas)
    u = WPI.inverse([0.0, 5.0, 0.0], optimize=False)
    np.testing.assert_allclose(u, _modules([5.0] * 4, [0.0] * 4), atol=1e-12)
    np.testing.assert_allclose(WPI.twist(_modules([5.0] * 4, [0] * 4)), [0, 5, 0], atol=1e-12)
    # StraightStrafeInverseKinematics / StraightStrafeForwardKinematics(WithDeltas)
    u = WPI.inverse([0.0, 0.0, 5.0], optimize=False)
    np.testing.assert_allclose(u, _modules([5.0] * 4, [90.0] * 4), atol=1e-12)
    np.testing.assert_allclose(WPI.twist(_modules([5.0] * 4, [90] * 4)), [0, 0, 5], atol=1e-12)


def test_wpimath_turn_in_place():
    # TurnInPlaceInverseKinematics: 106.63 m/s at 135, 45, -135, -45 degrees for 2 pi rad/s
    u = WPI.inverse([2 * math.pi, 0.0, 0.0], optimize=False)
    np.testing.assert_allclose(u[:4], 106.63, atol=0.1)
    np.testing.assert_allclose(u[4:] / DEG, [135.0, 45.0, -135.0, -45.0], atol=0.1)
    # TurnInPlaceForwardKinematics(WithDeltas)
    tw = WPI.twist(_modules([106.629] * 4, [135, 45, -135, -45]))
    np.testing.assert_allclose(tw, [2 * math.pi, 0.0, 0.0], atol=0.1)


def test_wpimath_conserve_wheel_angle_at_standstill():
    # ConserveWheelAngle: after the turn in place, a zero command keeps 135/45/-135/-45.
    u = WPI.inverse([[2 * math.pi, 0.0, 0.0], [0.0, 0.0, 0.0]], optimize=False)
    np.testing.assert_allclose(u[1, :4], 0.0, atol=1e-12)
    np.testing.assert_allclose(u[1, 4:] / DEG, [135.0, 45.0, -135.0, -45.0], atol=1e-9)
    # ResetWheelAngle: a standstill from given headings keeps them (270 deg reads -90)
    start = np.array([0.0, 90.0, 180.0, 270.0]) * DEG
    u = WPI.inverse([0.0, 0.0, 0.0], current=start, optimize=False)
    np.testing.assert_allclose(u[:4], 0.0)
    np.testing.assert_allclose(wrap(u[4:] - start), 0.0, atol=1e-12)


def test_wpimath_off_centre_rotation():
    # OffCenterCORRotationInverseKinematics: 2 pi rad/s about the front-left module
    tw = _twist_about(2 * math.pi, 0.0, 0.0, (12.0, 12.0))
    u = WPI.inverse(tw, optimize=False)
    np.testing.assert_allclose(u[:4], [0.0, 150.796, 150.796, 213.258], atol=0.1)
    np.testing.assert_allclose(u[5:] / DEG, [0.0, -90.0, -45.0], atol=0.1)  # fl: speed 0
    # OffCenterCORRotationForwardKinematics(WithDeltas): 75.398, -75.398, 2 pi
    tw = WPI.twist(_modules([0.0, 150.796, 150.796, 213.258], [0, 0, -90, -45]))
    np.testing.assert_allclose(tw, [2 * math.pi, 75.398, -75.398], atol=0.1)


def test_wpimath_off_centre_rotation_and_translation():
    # OffCenterCORRotationAndTranslationInverseKinematics: (0, 3 m/s, 1.5 rad/s) about (24, 0)
    tw = _twist_about(1.5, 0.0, 3.0, (24.0, 0.0))
    u = WPI.inverse(tw, optimize=False)
    np.testing.assert_allclose(u[:4], [23.43, 23.43, 54.08, 54.08], atol=0.1)
    np.testing.assert_allclose(u[4:] / DEG, [-140.19, -39.81, -109.44, -70.56], atol=0.1)
    # ...ForwardKinematics(WithDeltas): vx 0, vy -33, omega 1.5 at the body origin
    tw = WPI.twist(_modules([23.43, 23.43, 54.08, 54.08], [-140.19, -39.81, -109.44, -70.56]))
    np.testing.assert_allclose(tw, [1.5, 0.0, -33.0], atol=0.1)


def test_wpimath_desaturate():
    # Desaturate: 5, 6, 4, 7 m/s limited to 5.5 scale by 5.5 / 7
    np.testing.assert_allclose(desaturate([5.0, 6.0, 4.0, 7.0], 5.5), np.r_[5, 6, 4, 7] * 5.5 / 7)
    # DesaturateNegativeVelocity: 1, 1, -2, -2 limited to 1
    np.testing.assert_allclose(desaturate([1.0, 1.0, -2.0, -2.0], 1.0), [0.5, 0.5, -1.0, -1.0])
    np.testing.assert_allclose(desaturate([[0.1, 0.2]], 1.0), [[0.1, 0.2]])  # within: unchanged
    # inverse with max_increment keeps the module angles and scales the twist
    tw = np.array([0.3, 2.0, 1.0])
    u = WPI.inverse(tw, max_increment=1.0, optimize=False)
    assert np.max(np.abs(u[:4])) == pytest.approx(1.0)
    free = WPI.inverse(tw, optimize=False)
    np.testing.assert_allclose(u[4:], free[4:], atol=1e-12)
    np.testing.assert_allclose(WPI.twist(u), tw / np.max(np.abs(free[:4])), atol=1e-12)


def test_wpimath_module_optimize():
    # SwerveModuleVelocityTest Optimize: (-2 m/s, 180 deg) from 45 deg -> (2, 0);
    # (4.7, 41 deg) from -50 deg -> (-4.7, -139 deg)
    a, s = optimize_angles([[math.pi, 41 * DEG]], current=[45 * DEG, -50 * DEG])
    np.testing.assert_allclose(wrap(a[0] - [0.0, -139 * DEG]), 0.0, atol=1e-12)
    np.testing.assert_allclose(s[0] * [-2.0, 4.7], [2.0, -4.7])
    # NoOptimize: (2, 89 deg) and (-2, -2 deg) from 0 stay as they are
    a, s = optimize_angles([[89 * DEG, -2 * DEG]], current=[0.0, 0.0])
    np.testing.assert_allclose(a[0], [89 * DEG, -2 * DEG], atol=1e-12)
    np.testing.assert_allclose(s[0], [1.0, 1.0])


def test_wpimath_odometry_two_iterations_and_90_degree_turn():
    # SwerveDriveOdometryTest TwoIterations: 0.5 m at 0 deg on every module -> x = 0.5
    tw = WPI.twist(_modules([0.5] * 4, [0] * 4))
    np.testing.assert_allclose(body_increment(tw, "exact", False)[0], [0.5, 0, 0], atol=1e-12)
    # 90DegreeTurn: fl 18.85 m @ 90, fr 42.15 @ 26.565, bl 18.85 @ -90, br 42.15 @ -26.565
    # -> (12, 12, 90 deg) within 0.01. wpimath takes the heading from the gyro; our least-squares
    # twist gives it from the wheels alone, and the exponential then lands on the same pose.
    tw = WPI.twist(_modules([18.85, 42.15, 18.85, 42.15], [90, 26.565, -90, -26.565]))
    pose = body_increment(tw, "exact", False)[0]
    np.testing.assert_allclose(pose[:2], [12.0, 12.0], atol=0.01)
    assert pose[2] / DEG == pytest.approx(90.0, abs=0.01)


# --------------------------------------------------------------------------- our own properties
GEOM = {
    "wheel_radius": [0.05, 0.05, 0.051, 0.049],
    "modules": [[0.3, 0.25], [0.3, -0.25], [-0.3, 0.25], [-0.3, -0.25]],
}


@pytest.mark.parametrize(
    "u",
    [
        np.r_[1.0, -2.0, 0.5, 3.0, 0.3, -1.2, 2.9, -2.5],  # general
        np.r_[1.0, 2.0, 3.0, 4.0, [math.pi / 2] * 4],  # every module at 90 degrees
        np.r_[0.0, 0.0, 0.0, 0.0, 0.4, -0.4, 1.0, 2.0],  # zero speed
        np.r_[[2.0] * 4, [0.0] * 4],  # straight driving
        np.r_[0.0, 1.0, 0.0, -1.0, math.pi / 2, 0.0, -math.pi, 1.0],  # mixed singular
    ],
    ids=["general", "all-at-90-deg", "zero-speed", "straight", "mixed"],
)
def test_jacobian_matches_central_differences(u):
    d = make_drive("swerve", **GEOM)
    np.testing.assert_allclose(d.J_twist_u(u), numerical_jacobian(d.twist, u), atol=1e-8)
    if np.all(u[:4] == 0):  # at standstill the steering angles carry no motion
        np.testing.assert_allclose(d.J_twist_u(u)[:, 4:], 0.0)
    batch = np.vstack([u, u + 0.1])
    np.testing.assert_allclose(d.J_twist_u(batch)[1], d.J_twist_u(u + 0.1))


def test_inverse_round_trip_flip_and_continuity():
    d = make_drive("swerve", **GEOM)
    rng = np.random.default_rng(5)
    T = rng.normal(0.0, 0.3, (200, 3))
    U = d.inverse(T)
    np.testing.assert_allclose(d.twist(U), T, atol=1e-12)
    # the flip keeps every module within 90 degrees of its previous angle
    steps = wrap(np.diff(np.vstack([np.zeros(4), U[:, 4:]]), axis=0))
    assert np.all(np.abs(steps) <= math.pi / 2 + 1e-12)
    raw = d.inverse(T, optimize=False)
    assert np.all(raw[:, :4] >= 0) and np.any(U[:, :4] < 0)  # flips happened, speeds signed


def test_geometry_errors_name_the_key():
    with pytest.raises(ValueError, match="modules"):
        make_drive("swerve", wheel_radius=0.05, modules=[[0.1, 0.1]])
    with pytest.raises(ValueError, match="modules"):
        make_drive("swerve", wheel_radius=0.05, modules=[[0.1, 0.1], [0.1, 0.1]])
    with pytest.raises(ValueError, match="wheel_radius"):
        make_drive("swerve", wheel_radius=[0.05, -1], modules=[[0, 1], [0, -1]])
    d = make_drive("swerve", wheel_radius=0.05, modules=[[0, 1], [0, -1], [1, 0]])
    assert d.input_names == ("w1", "w2", "w3", "s1", "s2", "s3")
    assert d.input_kinds == ("wheel",) * 3 + ("steer",) * 3
    np.testing.assert_allclose(d.icr([1.0, 0.0, 2.0]), [-2.0, 0.0])
