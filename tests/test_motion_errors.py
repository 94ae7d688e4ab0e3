"""Reference values of the honest error models (issue 11 item 1).

The increments drive's distance-driven heading variance is checked against Siegwart &
Nourbakhsh's two-wheel model (ch. 5, ``004_f4547100a083f338.txt``):
``var(dtheta) = (k_r |ds_r| + k_l |ds_l|) / b^2`` computed by odofuse's differential drive.
"""

import numpy as np
import pytest

from odofuse.config import config_from_dict
from odofuse.drives import make_drive
from odofuse.errors import ConfigError
from odofuse.estimators.ekf import FastIncrement
from odofuse.motion import MotionModel, error_model_from_config, implied_k_theta_ds

K_W, B = 2e-4, 0.5  # wheel k (m^2 per m) and track (m) of the reference two-wheel robot


def _heading_var_differential(twist):
    d = make_drive("differential", wheel_radius=0.1, track_width=B)
    model = MotionModel(d, error_model_from_config(d, {"k_r": K_W, "k_l": K_W}))
    u = d.inverse(np.asarray(twist, dtype=float))
    ds = np.abs(d.travel(u))
    # Siegwart's closed form, and odofuse's propagation through the drive Jacobian
    siegwart = K_W * ds.sum() / B**2
    _, J = model.increment(u)
    return siegwart, float((J[2] ** 2) @ model.errors.variances(d, u))


def test_implied_k_theta_ds_is_the_two_wheel_value():
    k_ds, k_dtheta = K_W / 2, K_W / B  # straight: var(ds) = k_w/2 |ds|; spin: k_w/b |dtheta|
    assert implied_k_theta_ds(k_ds, k_dtheta) == pytest.approx(2 * K_W / B**2)  # 1.6e-3
    assert implied_k_theta_ds(1e-4, 0.0) == 0.0
    with pytest.raises(ValueError, match="k_theta_ds"):
        implied_k_theta_ds(0.0, 1e-4)


@pytest.mark.parametrize("twist", [[0.0, 1.0, 0.0], [0.7, 0.0, 0.0]])
def test_increments_heading_variance_matches_siegwart_straight_and_spinning(twist):
    siegwart, propagated = _heading_var_differential(twist)
    assert propagated == pytest.approx(siegwart, rel=1e-12)
    inc = make_drive("increments")
    errors = error_model_from_config(inc, {"k": [K_W / 2, K_W / B]})
    u = np.array([twist[1], twist[0]])  # (ds, dtheta)
    assert errors.variances(inc, u)[1] == pytest.approx(siegwart, rel=1e-12)


def test_increments_heading_never_perfect_when_driving_straight():
    inc = make_drive("increments")
    var = error_model_from_config(inc, {}).variances(inc, np.array([2.0, 0.0]))
    # defaults k = 1e-4 for both inputs: k_theta_ds = 1e-4^2 / 1e-4 = 1e-4 rad^2/m
    np.testing.assert_allclose(var, [2e-4, 2e-4])
    off = error_model_from_config(inc, {"k_theta_ds": 0.0}).variances(inc, np.array([2.0, 0.0]))
    np.testing.assert_allclose(off, [2e-4, 0.0])


def test_per_second_floor_and_fast_path():
    inc = make_drive("increments")
    errors = error_model_from_config(
        inc, {"k": [1e-2, 1e-4], "k_theta_ds": 3e-4, "var_floor": 1e-8, "var_rate": [0.0, 2e-6]}
    )
    u = np.array([0.3, -0.05])
    base = [1e-2 * 0.3 + 1e-8, 1e-4 * 0.05 + 3e-4 * 0.3 + 1e-8]
    np.testing.assert_allclose(errors.variances(inc, u), base, rtol=1e-12)
    np.testing.assert_allclose(errors.variances(inc, u, 0.5), [base[0], base[1] + 1e-6])
    fast = FastIncrement(MotionModel(inc, errors))
    assert fast.ok
    _, _, var = fast(u, 0.5)
    np.testing.assert_allclose(var, errors.variances(inc, u, 0.5), rtol=1e-12)
    *_, G = fast.terms(u, 0.5)
    assert np.asarray(G)[2, 1] ** 2 == pytest.approx(base[1] + 1e-6, rel=1e-12)


def test_thrun_alphas_on_increments():
    inc = make_drive("increments")
    errors = error_model_from_config(inc, {"k": 0.0, "alphas": [0.1, 0.2, 0.3, 0.4]})
    u = np.array([0.5, 0.2])
    # Probabilistic Robotics Table 5.3 on variances: a1 v^2 + a2 w^2, a3 v^2 + a4 w^2
    np.testing.assert_allclose(
        errors.variances(inc, u), [0.1 * 0.25 + 0.2 * 0.04, 0.3 * 0.25 + 0.4 * 0.04]
    )


def _cfg(motion, estimator="ekf", drive="increments"):
    robot = {"drive": drive}
    if drive == "differential":
        robot.update(wheel_radius=0.1, track_width=0.5)
    return {"log": "builtin:plaza1", "robot": robot, "motion": motion, "estimator": estimator}


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="motion.k_theta_ds"):
        config_from_dict(_cfg({"k_theta_ds": 1e-3}, drive="differential"))
    with pytest.raises(ConfigError, match="motion.var_rate"):
        config_from_dict(_cfg({"var_rate": 1e-6}, estimator="smoother"))
    assert config_from_dict(_cfg({"var_rate": 1e-6})).motion.var_rate == 1e-6
