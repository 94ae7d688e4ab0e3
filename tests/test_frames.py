"""Tests of odofuse.frames (Modern Robotics 13.5, 000 source)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse import se2
from odofuse.frames import T_sb, end_effector


def trans(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def rot_z(a):
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return T


def test_T_sb_embeds_the_planar_pose():
    rng = np.random.default_rng(0)
    Q = np.column_stack([rng.uniform(-5, 5, (10, 2)), rng.uniform(-math.pi, math.pi, 10)])
    T = T_sb(Q, z=0.0963)
    assert T.shape == (10, 4, 4)
    planar = se2.to_matrix(Q)  # (N, 3, 3) homogeneous SE(2), an independent construction
    np.testing.assert_allclose(T[:, :2, :2], planar[:, :2, :2], atol=1e-15)
    np.testing.assert_allclose(T[:, :2, 3], Q[:, :2], atol=1e-15)
    np.testing.assert_allclose(T[:, 2], np.tile([0, 0, 1, 0.0963], (10, 1)))
    np.testing.assert_allclose(T[:, 3], np.tile([0, 0, 0, 1], (10, 1)))
    np.testing.assert_allclose(T_sb(Q[3], z=0.0963), T[3])


def test_end_effector_known_offset_youbot_like():
    # MR youBot numbers: T_b0 offset (0.1662, 0, 0.0026), M_0e (0.033, 0, 0.6546), z_b 0.0963
    q = [1.0, 2.0, math.pi / 2]
    X = end_effector(q, trans(0.1662, 0, 0.0026), trans(0.033, 0, 0.6546), z=0.0963)
    expected = rot_z(math.pi / 2)
    expected[:3, 3] = (1.0, 2.0 + 0.1662 + 0.033, 0.0963 + 0.0026 + 0.6546)
    np.testing.assert_allclose(X, expected, atol=1e-15)


def test_end_effector_with_arm_forward_kinematics():
    def arm(theta):  # one revolute joint about z_0, link of 0.5 m
        return rot_z(theta[0]) @ trans(0.5, 0, 0)

    T_b0 = trans(0.2, 0.0, 0.1)
    q = np.array([[0.0, 0.0, 0.0], [1.0, -1.0, math.pi]])
    theta = np.array([[math.pi / 2], [0.0]])
    X = end_effector(q, T_b0, arm, theta=theta)
    assert X.shape == (2, 4, 4)
    np.testing.assert_allclose(X[0, :3, 3], [0.2, 0.5, 0.1], atol=1e-15)
    np.testing.assert_allclose(X[1, :3, 3], [1.0 - 0.7, -1.0, 0.1], atol=1e-15)
    np.testing.assert_allclose(X[0, :3, :3], rot_z(math.pi / 2)[:3, :3], atol=1e-15)
    # the same theta for every pose
    X_same = end_effector(q, T_b0, arm, theta=[0.0])
    np.testing.assert_allclose(X_same[1], X[1], atol=1e-15)


def test_end_effector_bad_input():
    with pytest.raises(ValueError, match="theta is required"):
        end_effector([0, 0, 0], np.eye(4), lambda th: np.eye(4))
    with pytest.raises(ValueError, match="T_b0"):
        end_effector([0, 0, 0], np.eye(3), np.eye(4))
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(ValueError, match="orthonormal"):
        end_effector([0, 0, 0], np.eye(4), bad)
    with pytest.raises(ValueError, match="shape"):
        T_sb([0.0, 1.0])
