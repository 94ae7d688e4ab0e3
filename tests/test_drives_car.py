"""Rear-encoder cars, wheels_per_side, the twist drive, base_frame_offset and euler_end.

Peer values: ros-controls/ros2_controllers (commit 94e74de3),
``steering_controllers_library/test/test_steering_odometry.cpp``. Conventions: their
``set_wheel_params(wheel_radius, wheelbase, wheel_track)`` is our ``wheel_radius``,
``wheelbase`` and ``track_width`` (one value for the traction and the steering track); their
``update_from_velocity`` takes wheel speeds (rad/s), right wheel first, and ``dt``; our inputs
are the step's increments ``speed * dt``, left first. ``get_linear`` / ``get_angular`` are our
twist divided by ``dt``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.drives import Bicycle, Car, CarAckermann, Differential, make_drive
from odofuse.motion import (
    INTEGRATORS,
    MotionModel,
    OdometryErrorModel,
    body_increment,
    dead_reckon,
    error_model_from_config,
    side_outliers,
)
from odofuse.testing import numerical_jacobian

CAR = Car(0.3, 2.5, 1.5)
ACK = CarAckermann(0.3, 2.5, 1.5, steering_track_width=1.3)


# --------------------------------------------------------------------------- ros2_controllers
def test_ros2_ackermann_odometry():
    # TEST(TestSteeringOdometry, ackermann_odometry): params (1, 1, 1),
    # update_from_velocity(right 1, left 1, right steer .1, left steer .1, dt .1):
    # linear 1.002, angular .1, x .1, heading .01 (all within 1e-3)
    d = CarAckermann(1.0, 1.0, 1.0)
    dt = 0.1
    tw = d.twist([1.0 * dt, 1.0 * dt, 0.1, 0.1])
    assert tw[1] / dt == pytest.approx(1.002, abs=1e-3)
    assert tw[0] / dt == pytest.approx(0.1, abs=1e-3)
    pose = body_increment(tw, "rk2", False)[0]
    assert pose[0] == pytest.approx(0.1, abs=1e-3)
    assert pose[2] == pytest.approx(0.01, abs=1e-3)


def test_ros2_tricycle_odometry():
    # TEST(TestSteeringOdometry, tricycle_odometry): params (1, 1, 1),
    # update_from_velocity(right 1, left 1, steer .1, dt .1): the same four numbers
    d = Car(1.0, 1.0, 1.0)
    dt = 0.1
    tw = d.twist([1.0 * dt, 1.0 * dt, 0.1])
    assert tw[1] / dt == pytest.approx(1.002, abs=1e-3)
    assert tw[0] / dt == pytest.approx(0.1, abs=1e-3)
    pose = body_increment(tw, "rk2", False)[0]
    assert pose[0] == pytest.approx(0.1, abs=1e-3) and pose[2] == pytest.approx(0.01, abs=1e-3)
    # the exact per-wheel correction behind 1.002: R = L / tan(.1), v = mean(v R / (R -+ T/2))
    R = 1.0 / math.tan(0.1)
    assert tw[1] / dt == pytest.approx(0.5 * (R / (R + 0.5) + R / (R - 0.5)), rel=1e-14)


def test_ros2_bicycle_odometry():
    # TEST(TestSteeringOdometry, bicycle_odometry): params (1, 1, 1),
    # update_from_velocity(1, steer .1, dt .1): linear 1.0, angular .1, x .1, heading .01
    tw = Bicycle(1.0, 1.0).twist([0.1, 0.1])
    assert tw[1] / 0.1 == pytest.approx(1.0, abs=1e-3) and tw[0] / 0.1 == pytest.approx(
        0.1, abs=1e-3
    )


@pytest.mark.parametrize(
    "initial,linear,angular,dt",
    [
        ((0.0, 0.0, 0.0), 2.0, 0.0, 0.5),
        ((-1.2, 0.7, 0.4), 1.1, 0.0, 0.35),
        ((0.0, 0.0, 0.0), 1.0, 1.0, 1.0),
        ((0.0, 0.0, 0.0), 1.0, -1.0, 1.0),
        ((0.8, -0.45, -0.3), 1.3, 0.45, 0.6),
        ((0.8, -0.45, -0.3), 1.3, -0.45, 0.6),
    ],
)
def test_ros2_open_loop_integration(initial, linear, angular, dt):
    # SteeringOdometryIntegratorTest integrates_open_loop_straight / _arcs (tolerance 1e-10):
    # update_open_loop(linear, angular, dt) lands on the circular-arc pose. Our twist drive
    # with the exact integrator, fed cmd_vel (linear, angular) for dt:
    model = MotionModel(make_drive("twist"), OdometryErrorModel((0.0, 0.0), (0.0, 0.0)))
    poses, _ = dead_reckon(
        model, np.array(initial), np.zeros((3, 3)), [[linear * dt, angular * dt]]
    )
    x0, y0, h0 = initial
    h1 = h0 + angular * dt
    if angular == 0.0:
        expect = (x0 + linear * math.cos(h0) * dt, y0 + linear * math.sin(h0) * dt, h1)
    else:
        R = linear / angular
        expect = (
            x0 + R * (math.sin(h1) - math.sin(h0)),
            y0 - R * (math.cos(h1) - math.cos(h0)),
            h1,
        )
    np.testing.assert_allclose(poses[-1], expect, atol=1e-10)


def test_ros2_ackermann_inverse_kinematics_signs():
    # ackermann_IK_left / _right: turning left the right (outer) wheel is faster and its steering
    # smaller than the left (inner) one; mirrored to the right. Straight: equal, no steering.
    u = ACK.inverse([0.1, 1.0, 0.0])
    assert u[1] > u[0] > 0 and 0 < u[3] < u[2]
    u = ACK.inverse([-0.1, 1.0, 0.0])
    assert u[0] > u[1] > 0 and u[3] < u[2] < 0 and abs(u[3]) > abs(u[2])
    np.testing.assert_array_equal(ACK.inverse([0.0, 1.0, 0.0])[2:], 0.0)


# --------------------------------------------------------------------------- Jacobians
CASES = [
    (CAR, [1.0, 1.2, 0.3]),
    (CAR, [1.0, 1.0, 0.0]),  # straight
    (CAR, [0.0, 0.0, 0.7]),  # zero speed
    (CAR, [-1.0, 1.0, math.pi / 2]),  # turning about the rear axle midpoint
    (CAR, [0.4, 2.0, -1.2]),
    (ACK, [1.0, 1.2, 0.3, 0.25]),
    (ACK, [1.0, 1.0, 0.0, 0.0]),  # straight
    (ACK, [0.0, 0.0, 0.5, 0.4]),  # zero speed
    (ACK, [0.5, 0.8, -0.6, -0.5]),
]


@pytest.mark.parametrize("drive,u", CASES)
def test_car_jacobians_match_central_differences(drive, u):
    u = np.asarray(u, dtype=float)
    np.testing.assert_allclose(drive.J_twist_u(u), numerical_jacobian(drive.twist, u), atol=1e-8)


def test_car_is_a_differential_drive_at_90_degrees_and_the_mean_when_straight():
    diff = Differential(0.3, 1.5)
    np.testing.assert_allclose(
        CAR.twist([-1.0, 1.0, math.pi / 2]), diff.twist([-1.0, 1.0]), atol=1e-15
    )
    np.testing.assert_allclose(CAR.twist([1.0, 1.4, 0.0]), [0.0, 0.3 * 1.2, 0.0])


def test_car_refuses_a_rear_wheel_at_the_icr_and_round_trips():
    phi = math.atan(2.5 / 0.75)  # R = track_width / 2: the left wheel sits at the ICR
    with pytest.raises(ValueError, match="row 0.*centre of rotation"):
        CAR.twist([1.0, 1.0, phi])
    T = np.random.default_rng(1).normal(0, 0.2, (50, 3)) * [1, 1, 0]
    for d in (CAR, ACK):
        np.testing.assert_allclose(d.twist(d.inverse(T)), T, atol=1e-12)
    np.testing.assert_allclose(CAR.twist(CAR.inverse([0.5, 0.0, 0.0])), [0.5, 0.0, 0.0], atol=1e-15)
    with pytest.raises(ValueError, match="on the spot"):
        ACK.inverse([0.5, 0.0, 0.0])
    with pytest.raises(ValueError, match="v_y"):
        CAR.inverse([0.0, 1.0, 0.1])


# --------------------------------------------------------------------------- wheels per side
def test_wheels_per_side_matrix_noise_and_flags():
    one = Differential(0.1, 0.5)
    three = make_drive("differential", wheel_radius=0.1, track_width=0.5, wheels_per_side=3)
    assert three.input_names == ("left1", "left2", "left3", "right1", "right2", "right3")
    np.testing.assert_allclose(three.twist([1, 1, 1, 2, 2, 2]), one.twist([1, 2]))
    np.testing.assert_allclose(three.matrix().sum(axis=1), one.matrix().sum(axis=1), atol=1e-15)
    model = MotionModel(three, error_model_from_config(three, {"k_l": 1e-4, "k_r": 2e-4}))
    assert model.errors.k == (1e-4,) * 3 + (2e-4,) * 3
    # each side's variance falls as 1/n: three wheels, a third of one wheel's
    m1 = MotionModel(one, error_model_from_config(one, {"k": 1e-4}))
    m3 = MotionModel(three, error_model_from_config(three, {"k": 1e-4}))
    var1 = m1.input_cov([1.0, 1.0])
    var3 = m3.input_cov([1.0] * 6)
    F1, F3 = one.matrix(), three.matrix()
    np.testing.assert_allclose(F3 @ var3 @ F3.T, F1 @ var1 @ F1.T / 3, rtol=1e-12, atol=1e-22)
    # a slipping wheel: flagged, its mates not; within noise nothing is flagged
    U = np.array(
        [
            [1.0, 1.0, 1.0, 2.0, 2.0, 2.0],
            [1.0, 1.2, 1.0, 2.0, 2.0, 2.0],
            [1.0, 1.0 + 1e-4, 1.0, 2.0, 2.0, 2.0 - 1e-4],
        ]
    )
    flags = side_outliers(m3, U)
    np.testing.assert_array_equal(flags[1], [False, True, False, False, False, False])
    assert not flags[0].any() and not flags[2].any()
    two = make_drive("skid_steer", wheel_radius=0.1, track_width=0.5, wheels_per_side=2)
    m2 = MotionModel(two, error_model_from_config(two, {"k": 1e-4}))
    np.testing.assert_array_equal(side_outliers(m2, [[1.0, 1.3, 2.0, 2.0]])[0], [1, 1, 0, 0])
    assert not side_outliers(m1, [[1.0, 5.0]]).any()  # one wheel per side: nothing to compare


def test_a_slipping_wheel_is_down_weighted_and_counted():
    from odofuse.estimators.common import odometry_inputs
    from odofuse.io.log import SensorLog, Stream

    three = make_drive("differential", wheel_radius=0.1, track_width=0.5, wheels_per_side=3)
    model = MotionModel(three, error_model_from_config(three, {"k": 1e-4}))
    steps = np.tile([0.5, 0.5, 0.5, 0.6, 0.6, 0.6], (20, 1))
    steps[7, 2] = 0.9  # left3 spins
    cum = np.vstack([np.zeros(6), np.cumsum(steps, axis=0)])
    stream = Stream("wheels", "mem", np.arange(21) * 0.1, three.input_names, cum)
    log = SensorLog("mem", {"wheels": stream}, {}, None, {})
    _, U = odometry_inputs(log, model)
    np.testing.assert_allclose(U[7], [0.5, 0.5, 0.5, 0.6, 0.6, 0.6])  # replaced by its mates
    assert log.repairs == {"wheels.side_outliers": 1, "wheels.side_outliers_replaced": 1}


# --------------------------------------------------------------------------- twist, offset
def test_twist_drive_thrun_velocity_noise():
    d = make_drive("twist")
    assert d.input_names == ("v", "w") and d.input_kinds == ("velocity", "velocity")
    errors = error_model_from_config(d, {"k": 0.0, "alphas": [0.1, 0.2, 0.3, 0.4]})
    u = np.array([0.5, 0.2])  # v dt, w dt
    # Probabilistic Robotics Table 5.3 on variances: a1 v^2 + a2 w^2, a3 v^2 + a4 w^2
    np.testing.assert_allclose(
        errors.variances(d, u), [0.1 * 0.25 + 0.2 * 0.04, 0.3 * 0.25 + 0.4 * 0.04]
    )
    with pytest.raises(ValueError, match="twist drive"):
        error_model_from_config(CAR, {"alphas": [0.1, 0.2, 0.3, 0.4]})
    with pytest.raises(ValueError, match="v_y|range"):
        d.inverse([0.1, 1.0, 0.2])
    h = make_drive("twist", holonomic=True)
    np.testing.assert_allclose(h.twist([1.0, 2.0, 3.0]), [3.0, 1.0, 2.0])


def test_base_frame_offset_is_the_adjoint():
    gtsam = pytest.importorskip("gtsam")
    offset = (0.1, -0.05, 0.3)
    inner = make_drive("mecanum4", wheel_radius=0.05, half_length=0.2, half_width=0.15)
    d = make_drive(
        "mecanum4",
        wheel_radius=0.05,
        half_length=0.2,
        half_width=0.15,
        base_frame_offset=list(offset),
    )
    u = np.array([1.0, -0.5, 2.0, 0.3])
    xi_c = inner.twist(u)
    # gtsam Pose2 tangent is [vx, vy, omega]: twist_B = Ad(T^-1) twist_C with T = pose of B in C
    T = gtsam.Pose2(*offset)
    ad = T.inverse().AdjointMap() @ np.array([xi_c[1], xi_c[2], xi_c[0]])
    np.testing.assert_allclose(d.twist(u), [ad[2], ad[0], ad[1]], atol=1e-14)
    # and exactly: the base frame moves by T^-1 exp(xi_C) T
    moved = T.inverse().compose(gtsam.Pose2.Expmap([xi_c[1], xi_c[2], xi_c[0]])).compose(T)
    np.testing.assert_allclose(
        body_increment(d.twist(u), "exact", False)[0],
        [moved.x(), moved.y(), moved.theta()],
        atol=1e-14,
    )
    np.testing.assert_allclose(d.J_twist_u(u), numerical_jacobian(d.twist, u), atol=1e-9)
    np.testing.assert_allclose(d.twist(d.inverse(d.twist(u))), d.twist(u), atol=1e-13)
    assert d.name == "mecanum4" and d.input_names == inner.input_names
    with pytest.raises(ValueError, match="base_frame_offset"):
        make_drive("differential", wheel_radius=0.1, track_width=0.5, base_frame_offset=[1, 2])


def test_euler_end_integrator():
    # heading first, then position along the new heading (ros2_controllers mecanum Odometry::update)
    assert "euler_end" in INTEGRATORS
    tw = np.array([0.4, 1.0, 0.2])
    d, J = body_increment(tw, "euler_end")
    c, s = math.cos(0.4), math.sin(0.4)
    np.testing.assert_allclose(d, [c * 1.0 - s * 0.2, s * 1.0 + c * 0.2, 0.4])
    num = numerical_jacobian(lambda x: body_increment(x, "euler_end", False)[0], tw)
    np.testing.assert_allclose(J, num, atol=1e-9)
    # the vectorised dead reckoning and its covariance agree with step-by-step prediction
    drive = Differential(0.1, 0.5)
    model = MotionModel(drive, OdometryErrorModel((1e-4, 2e-4), (1e-8, 1e-8)), "euler_end")
    U = np.random.default_rng(2).normal(1.0, 0.5, (30, 2))
    poses, covs = dead_reckon(model, np.zeros(3), np.eye(3) * 1e-4, U)
    p, P = np.zeros(3), np.eye(3) * 1e-4
    for u in U:
        p, P, _, _ = model.predict(p, P, u)
    np.testing.assert_allclose(poses[-1], p, atol=1e-12)
    np.testing.assert_allclose(covs[-1], P, atol=1e-12)
