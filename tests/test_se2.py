"""SE(2) algebra against gtsam.Pose2 (an independent oracle) and numerical Jacobians."""

import gtsam
import mpmath
import numpy as np
import pytest

from odofuse import se2
from odofuse.testing import numerical_jacobian

RNG = np.random.default_rng(20261121)
OMEGAS = [0.0, 1e-9, 1e-6, 1e-3, 1.0]


def pose2(p):
    return gtsam.Pose2(p[0], p[1], p[2])


def as_array(g):
    return np.array([g.x(), g.y(), g.theta()])


def random_poses(n):
    return np.column_stack([RNG.normal(0, 10, (n, 2)), RNG.uniform(-np.pi, np.pi, n)])


def test_wrap_range_and_boundaries():
    a = np.array([-np.pi, np.pi, 3 * np.pi, -3 * np.pi + 1e-12, 0.0, 7.0])
    w = se2.wrap(a)
    assert np.all(w >= -np.pi) and np.all(w < np.pi)
    assert w[1] == pytest.approx(-np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)


def test_compose_inverse_between_match_gtsam():
    a, b = random_poses(200), random_poses(200)
    for pa, pb, c, i, bt in zip(
        a, b, se2.compose(a, b), se2.inverse(a), se2.between(a, b), strict=True
    ):
        ga, gb = pose2(pa), pose2(pb)
        for ours, ref in ((c, ga.compose(gb)), (i, ga.inverse()), (bt, ga.between(gb))):
            d = ours - as_array(ref)
            d[2] = se2.wrap(d[2])
            assert np.abs(d).max() < 1e-12


def test_compose_is_the_head_to_tail_formula_of_the_002_source():
    a, b = np.array([1.0, 2.0, 0.5]), np.array([0.3, -0.4, 0.2])
    expected = [
        1.0 + 0.3 * np.cos(0.5) + 0.4 * np.sin(0.5),
        2.0 + 0.3 * np.sin(0.5) - 0.4 * np.cos(0.5),
        0.7,
    ]
    np.testing.assert_allclose(se2.compose(a, b), expected, atol=1e-15)


def test_exp_and_log_match_gtsam_on_random_twists():
    # exp keeps the increment's dtheta unwrapped; Pose2 wraps it: compare on the circle.
    for w, vx, vy in np.column_stack([RNG.uniform(-3.1, 3.1, 200), RNG.normal(0, 2, (200, 2))]):
        twist = np.array([w, vx, vy])
        ref = gtsam.Pose2.Expmap(np.array([vx, vy, w]))
        d = se2.exp(twist) - as_array(ref)
        d[2] = se2.wrap(d[2])
        assert np.abs(d).max() < 1e-12
        log_ref = gtsam.Pose2.Logmap(ref)
        assert np.abs(se2.log(as_array(ref)) - log_ref[[2, 0, 1]]).max() < 1e-12


def _exp_mp(w, vx, vy):
    """MR eq. 13.35 in 50-digit arithmetic: the oracle near omega = 0."""
    mpmath.mp.dps = 50
    w, vx, vy = (mpmath.mpf(float(v)) for v in (w, vx, vy))
    if w == 0:
        return np.array([float(vx), float(vy), 0.0])
    dx = (vx * mpmath.sin(w) + vy * (mpmath.cos(w) - 1)) / w
    dy = (vy * mpmath.sin(w) + vx * (1 - mpmath.cos(w))) / w
    return np.array([float(dx), float(dy), float(w)])


@pytest.mark.parametrize("w", OMEGAS + [-1e-6, 2.5])
def test_exp_is_accurate_near_zero_rotation_and_log_inverts(w):
    # gtsam.Pose2.Expmap itself loses ~1e-7 at omega = 1e-9 ((1 - cos w)/w cancels), so the
    # oracle here is the same formula in 50-digit arithmetic.
    for vx, vy in RNG.normal(0, 2, (20, 2)):
        twist = np.array([w, vx, vy])
        assert np.abs(se2.exp(twist) - _exp_mp(w, vx, vy)).max() < 1e-15 * 8
        assert np.abs(se2.log(se2.exp(twist)) - twist).max() < 1e-12


def test_exp_is_modern_robotics_13_35_and_the_icr_construction():
    # MR eq. 13.35 evaluated literally for omega != 0, and the centre-of-rotation construction
    # of the 001 source (T_bb' = T_bs T_ss' T_s'b').
    for w, vx, vy in RNG.normal(0, 1, (50, 3)):
        mr = [
            (vx * np.sin(w) + vy * (np.cos(w) - 1)) / w,
            (vy * np.sin(w) + vx * (1 - np.cos(w))) / w,
            w,
        ]
        tw = np.array([w, vx, vy])
        np.testing.assert_allclose(se2.exp(tw), mr, atol=1e-12)
        np.testing.assert_allclose(
            se2.to_matrix(se2.icr_construction(tw)), se2.to_matrix(se2.exp(tw)), atol=1e-12
        )
    assert np.array_equal(se2.exp([0.0, 0.3, -0.2]), [0.3, -0.2, 0.0])  # MR 13.35, omega = 0


@pytest.mark.parametrize("w", OMEGAS + [-1e-3, 0.049, 0.051])
def test_exp_jacobian_against_central_differences(w):
    tw = np.array([w, 0.8, -0.3])
    J = se2.J_exp(tw)
    # eps well above |w| would cross zero; the series branch and the closed form must agree.
    J_num = numerical_jacobian(se2.exp, tw, eps=1e-5)
    np.testing.assert_allclose(J, J_num, atol=1e-9)


def test_exp_jacobian_is_continuous_across_the_series_switch():
    w = np.array([0.05 - 1e-12, 0.05 + 1e-12])
    J = se2.J_exp(np.column_stack([w, np.ones(2), np.ones(2)]))
    np.testing.assert_allclose(J[0], J[1], atol=1e-13)


def test_compose_jacobians_against_central_differences_near_pi():
    b = np.array([0.5, 0.2, 0.1])
    for th in (np.pi - 1e-9, -np.pi + 1e-9, 0.3):
        a = np.array([1.0, -2.0, th])
        J_a, J_b = se2.J_compose(a, b)
        np.testing.assert_allclose(
            J_a, numerical_jacobian(lambda x: se2.compose(x, b), a, wrap_rows=[2]), atol=1e-8
        )
        np.testing.assert_allclose(
            J_b, numerical_jacobian(lambda x, a=a: se2.compose(a, x), b, wrap_rows=[2]), atol=1e-8
        )


def test_matrix_round_trip():
    p = random_poses(10)
    np.testing.assert_allclose(se2.from_matrix(se2.to_matrix(p)), p, atol=1e-12)
    np.testing.assert_allclose(
        se2.to_matrix(se2.compose(p[0], p[1])),
        se2.to_matrix(p[0]) @ se2.to_matrix(p[1]),
        atol=1e-12,
    )


def test_covariance_frame_conversion_matches_gtsam_and_monte_carlo():
    pose = np.array([2.0, -1.0, 2.2])
    A = RNG.normal(size=(3, 3))
    P_body = A @ A.T * 1e-4
    P_world = se2.cov_body_to_world(pose, P_body)
    np.testing.assert_allclose(se2.cov_world_to_body(pose, P_world), P_body, atol=1e-15)
    # Monte Carlo: perturb on the right in the tangent space (GTSAM convention).
    xi = RNG.multivariate_normal(np.zeros(3), P_body, 20000)
    g = pose2(pose)
    samples = np.array([as_array(g.compose(gtsam.Pose2.Expmap(x))) for x in xi])
    d = samples - pose
    d[:, 2] = se2.wrap(d[:, 2])
    np.testing.assert_allclose(np.cov(d.T), P_world, atol=5e-6)
