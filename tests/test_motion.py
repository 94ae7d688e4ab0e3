"""Integrators, the Siegwart error model and dead reckoning."""

import numpy as np
import pytest

from odofuse import se2
from odofuse.drives import Differential, Increments, make_drive
from odofuse.motion import (
    INTEGRATORS,
    MotionModel,
    OdometryErrorModel,
    ThrunOdometryModel,
    body_increment,
    dead_reckon,
    error_model_from_config,
    integrate,
)
from odofuse.testing import numerical_jacobian

RNG = np.random.default_rng(7)
R_WHEEL, B = 0.05, 0.3


def diff_model(integrator="exact", k=(2e-4, 1e-4), floor=(0.0, 0.0)):
    # inputs (left, right): k = (k_l, k_r)
    return MotionModel(Differential(R_WHEEL, B), OdometryErrorModel(k, floor), integrator)


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("w", [0.0, 1e-9, 1e-6, 1e-3, 1.0])
def test_integrator_jacobians_against_central_differences(integrator, w):
    pose = np.array([1.0, 2.0, np.pi - 1e-7])
    twist = np.array([w, 0.4, 0.1])
    _, F_p, J_pt = integrate(pose, twist, integrator)
    f_pose = lambda p: integrate(p, twist, integrator)[0]  # noqa: E731
    f_twist = lambda t: integrate(pose, t, integrator)[0]  # noqa: E731
    np.testing.assert_allclose(F_p, numerical_jacobian(f_pose, pose, wrap_rows=[2]), atol=1e-8)
    np.testing.assert_allclose(
        J_pt, numerical_jacobian(f_twist, twist, eps=1e-5, wrap_rows=[2]), atol=1e-8
    )


def test_exact_integration_is_the_twist_exponential_and_the_icc_formula():
    # Politecnico slides (003): x' = x + v/w (sin th' - sin th), y' = y - v/w (cos th' - cos th)
    for th, w, v in RNG.normal(0, 1, (50, 3)):
        pose = np.array([0.3, -0.7, th])
        new, _, _ = integrate(pose, [w, v, 0.0], "exact")
        th2 = th + w
        icc = [
            0.3 + v / w * (np.sin(th2) - np.sin(th)),
            -0.7 - v / w * (np.cos(th2) - np.cos(th)),
            se2.wrap(th2),
        ]
        np.testing.assert_allclose(new, icc, atol=1e-12)
        # MR 13.36: q_{k+1} = q_k + blockdiag(1, R(phi_k)) dq_b (here in [x, y, th] order)
        dq_b = se2.exp([w, v, 0.0])
        expected = pose + np.r_[se2.rot(th) @ dq_b[:2], dq_b[2]]
        expected[2] = se2.wrap(expected[2])
        np.testing.assert_allclose(new, expected, atol=1e-12)


def test_euler_and_rk2_are_the_slides_formulas():
    pose, (w, v) = np.array([1.0, 1.0, 0.4]), (0.2, 0.5)
    e, _, _ = integrate(pose, [w, v, 0.0], "euler")
    np.testing.assert_allclose(e, [1 + v * np.cos(0.4), 1 + v * np.sin(0.4), 0.6], atol=1e-15)
    r, _, _ = integrate(pose, [w, v, 0.0], "rk2")
    np.testing.assert_allclose(r, [1 + v * np.cos(0.5), 1 + v * np.sin(0.5), 0.6], atol=1e-15)


def test_euler_is_first_order_and_rk2_second_order():
    # A constant twist over a unit time split into n steps: the error of the end pose falls as
    # 1/n for Euler and 1/n^2 for RK2; exact is exact for every n.
    twist = np.array([1.2, 1.0, 0.0])
    truth = se2.exp(twist)
    errors = {k: [] for k in INTEGRATORS}
    for n in (10, 20, 40, 80):
        for integrator in INTEGRATORS:
            pose = np.zeros(3)
            for _ in range(n):
                pose, _, _ = integrate(pose, twist / n, integrator)
            errors[integrator].append(np.linalg.norm(pose[:2] - truth[:2]))
    for integrator, order in (("euler", 1), ("rk2", 2)):
        slopes = -np.diff(np.log(errors[integrator])) / np.log(2)
        np.testing.assert_allclose(slopes, order, atol=0.1)
    assert max(errors["exact"]) < 1e-13


def test_siegwart_error_model_reference_values():
    # Siegwart & Nourbakhsh ch. 5 (004): F_p, F_delta_rl, Sigma_delta = diag(k_r|ds_r|, k_l|ds_l|)
    model = diff_model("rk2", k=(2e-4, 1e-4))  # k_l, k_r
    pose = np.array([0.5, -0.2, 0.8])
    u = np.array([3.0, 4.0])  # wheel angles (left, right) in rad
    ds_l, ds_r = R_WHEEL * u
    ds, dth = (ds_r + ds_l) / 2, (ds_r - ds_l) / B
    a = pose[2] + dth / 2
    F_p_ref = np.array([[1, 0, -ds * np.sin(a)], [0, 1, ds * np.cos(a)], [0, 0, 1]])
    F_rl_ref = np.array(
        [
            [
                0.5 * np.cos(a) - ds / (2 * B) * np.sin(a),
                0.5 * np.cos(a) + ds / (2 * B) * np.sin(a),
            ],
            [
                0.5 * np.sin(a) + ds / (2 * B) * np.cos(a),
                0.5 * np.sin(a) - ds / (2 * B) * np.cos(a),
            ],
            [1 / B, -1 / B],
        ]
    )
    P = np.diag([0.01, 0.02, 0.003])
    new, P_new, F_p, F_u = model.predict(pose, P, u)
    np.testing.assert_allclose(new[:2], pose[:2] + ds * np.array([np.cos(a), np.sin(a)]))
    np.testing.assert_allclose(F_p, F_p_ref, atol=1e-15)
    # our inputs are wheel angles (left, right): F_u = F_delta_rl[:, (l, r)] * r
    np.testing.assert_allclose(F_u, F_rl_ref[:, ::-1] * R_WHEEL, atol=1e-15)
    Sigma_rl = np.diag([1e-4 * abs(ds_r), 2e-4 * abs(ds_l)])
    P_ref = F_p_ref @ P @ F_p_ref.T + F_rl_ref @ Sigma_rl @ F_rl_ref.T
    np.testing.assert_allclose(P_new, P_ref, atol=1e-16)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_dead_reckon_vectorised_equals_step_by_step(integrator):
    model = diff_model(integrator, floor=(1e-8, 2e-8))
    U = RNG.normal(1.0, 2.0, (3000, 2))
    # straight steps (omega = 0 exactly) and nearly straight ones (omega ~ 1e-9 .. 1e-3)
    U[::7, 1] = U[::7, 0]
    U[1::7, 1] = U[1::7, 0] + RNG.choice([1e-9, 1e-6, 1e-3], size=U[1::7].shape[0])
    pose0, P0 = np.array([10.0, -5.0, 3.0]), np.diag([0.01, 0.02, 0.003])
    poses, covs = dead_reckon(model, pose0, P0, U)
    pose, P = pose0, P0
    for k, u in enumerate(U):
        pose, P, _, _ = model.predict(pose, P, u)
        d = poses[k + 1] - pose
        d[2] = se2.wrap(d[2])
        assert np.abs(d).max() < 1e-9
        assert np.abs(covs[k + 1] - P).max() <= 1e-9 * max(1.0, np.abs(P).max())
    poses_only, none = dead_reckon(model, pose0, P0, U, with_cov=False)
    assert none is None and np.array_equal(poses_only, poses)


def test_dead_reckon_spans_several_covariance_blocks():
    # More steps than one closed-form block, so the hand-over between blocks is exercised.
    model = diff_model("exact")
    U = RNG.normal(0.5, 1.0, (20000, 2))
    poses, covs = dead_reckon(model, np.zeros(3), np.zeros((3, 3)), U)
    pose, P = np.zeros(3), np.zeros((3, 3))
    for u in U:
        pose, P, _, _ = model.predict(pose, P, u)
    assert np.abs(covs[-1] - P).max() <= 1e-9 * np.abs(P).max()
    assert np.all(np.linalg.eigvalsh(covs[1:]) > -1e-12)


def test_relative_preintegration_matches_composition():
    model = diff_model("exact", floor=(1e-6, 1e-6))
    U = RNG.normal(1.0, 0.5, (50, 2))
    delta, cov_body = model.relative(U)
    poses, covs = dead_reckon(model, np.zeros(3), np.zeros((3, 3)), U)
    np.testing.assert_allclose(delta, poses[-1])
    np.testing.assert_allclose(se2.cov_body_to_world(delta, cov_body), covs[-1], atol=1e-15)


def test_error_model_generalises_through_the_drive_jacobian():
    # Omni3: var(u_i) = k |r du_i| / r^2, and Q = F_u Sigma_u F_u^T with F_u through F = pinv(H(0)).
    drive = make_drive("omni3", wheel_radius=0.04, wheel_distance=0.2)
    model = MotionModel(drive, error_model_from_config(drive, {"k": 1e-3}), "exact")
    u = np.array([2.0, -1.0, 0.5])
    np.testing.assert_allclose(model.input_cov(u), np.diag(1e-3 * np.abs(u) / 0.04))
    pose = np.array([0.0, 0.0, 0.3])
    _, P, _, F_u = model.predict(pose, np.zeros((3, 3)), u)
    f = lambda x: model.predict(pose, np.zeros((3, 3)), x)[0]  # noqa: E731
    np.testing.assert_allclose(F_u, numerical_jacobian(f, u, wrap_rows=[2]), atol=1e-9)
    np.testing.assert_allclose(P, F_u @ model.input_cov(u) @ F_u.T, atol=1e-18)


def test_error_model_config_maps_k_r_k_l_and_steering():
    drive = Differential(0.05, 0.3)
    em = error_model_from_config(drive, {"k_r": 3e-4, "k_l": 1e-4})
    assert em.k == (1e-4, 3e-4)  # input order (left, right)
    with pytest.raises(ValueError, match="k_r/k_l"):
        error_model_from_config(Increments(), {"k_r": 1e-4})
    tri = make_drive("tricycle", wheel_radius=0.1, wheelbase=1.0)
    em = error_model_from_config(tri, {"k": 1e-3, "steer_sigma": 0.02})
    assert em.k[1] == 0.0 and em.floor[1] == pytest.approx(4e-4)


def test_thrun_model_variance_convention_and_linearisation():
    model = ThrunOdometryModel((0.01, 0.002, 0.03, 0.004))
    delta = np.array([1.0, 0.5, 0.7])
    rtr = model.decompose(delta)
    np.testing.assert_allclose(model.recompose(rtr), delta, atol=1e-15)
    r1, t, r2 = rtr
    np.testing.assert_allclose(
        model.variances(rtr),
        [
            0.01 * r1**2 + 0.002 * t**2,
            0.03 * t**2 + 0.004 * (r1**2 + r2**2),
            0.01 * r2**2 + 0.002 * t**2,
        ],
    )
    # Monte Carlo of the sampler against the linearised covariance (small noise).
    small = ThrunOdometryModel((1e-4, 1e-5, 1e-4, 1e-5))
    pose = np.array([1.0, 2.0, 0.3])
    samples = small.sample(np.random.default_rng(3), np.tile(pose, (40000, 1)), delta)
    new, P = small.covariance(pose, np.zeros((3, 3)), delta)
    d = samples - new
    d[:, 2] = se2.wrap(d[:, 2])
    np.testing.assert_allclose(np.cov(d.T), P, rtol=0.05, atol=1e-7)


def test_body_increment_rejects_unknown_integrator():
    with pytest.raises(ValueError, match="unknown integrator"):
        body_increment([0.1, 1.0, 0.0], "rk4")
