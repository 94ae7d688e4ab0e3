"""Dead reckoning's covariance with declared odometry calibration (issues 10 and 11).

``options.dead_reckoning.odometry_calibration`` adds the prior of the odometry's systematic
errors, unobserved, to the covariance (:func:`odofuse.estimators.dead_reckoning.
calibration_covariances`). Checked here: the poses never change and the plain run stays
bit-identical; for small sigmas the term equals the augmented EKF's prediction without
measurements (the estimate is quasi-Monte Carlo over the prior, exact in every regime up to its
sampling error); on simulated increment robots whose true systematic errors are drawn from the
declared prior the position NEES is inside issue 11's band (0.5x-2x of its dimension) where the
plain covariance is far above it; on Plaza2 the Plaza1 configs' default prior brings the NEES
into the band (RMSE unchanged).
"""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from odofuse.config import RunConfig, load_config
from odofuse.errors import ConfigError
from odofuse.estimators import run_estimator
from odofuse.estimators.common import initial_state, odometry_inputs
from odofuse.estimators.compiled.dead_reckoning import dead_reckon
from odofuse.evaluation import metrics
from odofuse.io.log import SensorLog, Stream
from odofuse.motion import motion_model_from_config

PACKAGE = Path(__file__).resolve().parents[1] / "odofuse"
SIGMA = (0.02, 0.02, 0.002)  # declared prior sigmas: ds scale, dtheta scale, heading bias rad/s


def _simulated(p_true, seed: int, steps: int = 3000, dt: float = 0.1):
    """Increments log of a robot whose measured inputs ``u_m`` relate to the true ones by
    ``u_true = (a ds_m, b dtheta_m + c dt)`` (``p_true = (a, b, c)``), plus white noise."""
    rng = np.random.default_rng(seed)
    k = np.arange(steps)
    u_true = np.column_stack([0.2 + 0.05 * np.sin(0.01 * k), 0.01 + 0.01 * np.cos(0.004 * k)])
    a, b, c = p_true
    u_meas = np.column_stack([u_true[:, 0] / a, (u_true[:, 1] - c * dt) / b])
    u_meas += rng.normal(0, 1, u_meas.shape) * np.sqrt(1e-4 * np.abs(u_meas) + 1e-8)
    poses = [np.zeros(3)]
    for ds, w in u_true:  # exact arcs
        x, y, th = poses[-1]
        f = 1.0 if w == 0 else math.sin(w / 2) / (w / 2)
        h = th + w / 2
        poses.append(np.array([x + ds * f * math.cos(h), y + ds * f * math.sin(h), th + w]))
    truth = np.array(poses)
    t = dt * np.arange(1, steps + 1)
    gt = np.column_stack([np.concatenate([[0.0], t]), truth])
    return SensorLog(
        "sim",
        {"odometry": Stream("odometry", "sim", t, ("ds", "dtheta"), u_meas)},
        {},
        Stream("groundtruth", "sim", gt[:, 0], ("x", "y", "theta"), gt[:, 1:]),
        initial_pose=truth[0],
    )


def _config(estimator="dead_reckoning", **opts):
    return RunConfig(
        log="sim",
        robot={"drive": "increments"},
        motion={"k": [1e-4, 1e-4], "k_theta_ds": 0.0, "var_floor": 1e-8, "integrator": "exact"},
        estimator=estimator,
        initial={"sigma": [0.01, 0.01, 0.001]},
        options={estimator: opts},
        source="sim.yaml",
    )


def test_without_calibration_the_run_is_the_plain_dead_reckoning_bit_for_bit():
    log = _simulated((1.01, 0.99, 0.001), seed=1)
    cfg = _config()
    model = motion_model_from_config(cfg)
    _, U = odometry_inputs(log, model)
    pose0, P0 = initial_state(cfg, log)
    poses, covs = dead_reckon(model, pose0, P0, U)
    for c in (cfg, _config(odometry_calibration=False)):
        res = run_estimator("dead_reckoning", log, c)
        assert np.array_equal(res.trajectory.poses, poses)
        assert np.array_equal(res.trajectory.covariances, covs)


def test_calibration_keeps_the_poses_and_only_widens_the_covariance():
    log = _simulated((1.01, 0.99, 0.001), seed=1)
    plain = run_estimator("dead_reckoning", log, _config())
    cal = run_estimator("dead_reckoning", log, _config(odometry_calibration=True))
    assert np.array_equal(cal.trajectory.poses, plain.trajectory.poses)
    extra = cal.trajectory.covariances - plain.trajectory.covariances
    assert np.array_equal(extra[0], np.zeros((3, 3)))  # the prior acts through the inputs
    assert np.all(np.linalg.eigvalsh(extra[1:]) > -1e-12)  # positive semi-definite
    assert np.all(np.linalg.eigvalsh(extra[-1])[-1] > 1.0)  # metres after 600 m


def test_small_prior_equals_the_augmented_ekf_prediction_without_measurements():
    """In the linear regime the prior's term is ``J Sigma_p J^T``: the pose block of the EKF's
    augmented prediction (odometry-calibration states, no walk, no sensor) minus the same EKF
    without them. The quasi-Monte Carlo estimate is within 2 % of each step's largest entry
    (0.9 % measured with 256 draws)."""
    log = _simulated((1.0, 1.0, 0.0), seed=2, steps=800)
    sig = [1e-4, 1e-4, 1e-5]
    ekf = {"odometry_calibration_sigma": sig, "odometry_calibration_walk": [0.0] * 3}
    with_cal = run_estimator("ekf", log, _config("ekf", odometry_calibration=True, **ekf))
    without = run_estimator("ekf", log, _config("ekf"))
    linear = (with_cal.trajectory.covariances - without.trajectory.covariances)[1:]
    cfg = _config(odometry_calibration=True, odometry_calibration_sigma=sig)
    dr = run_estimator("dead_reckoning", log, cfg)
    plain = run_estimator("dead_reckoning", log, _config())
    qmc = (dr.trajectory.covariances - plain.trajectory.covariances)[1:]
    scale = np.abs(linear).max(axis=(1, 2))
    assert scale[-1] > 1e-6
    assert np.all(np.abs(qmc - linear).max(axis=(1, 2)) <= 0.02 * scale)


def test_nees_is_in_band_when_the_true_errors_come_from_the_declared_prior():
    """Forty robots, each with its own systematic errors drawn from the declared prior (the
    situation the prior describes: another run of the robot, calibration unknown)."""
    rng = np.random.default_rng(11)
    cal_cfg = _config(odometry_calibration=True, odometry_calibration_sigma=list(SIGMA))
    with_cal, plain = [], []
    for seed in range(40):
        p = np.array([1.0, 1.0, 0.0]) + rng.normal(0.0, 1.0, 3) * SIGMA
        log = _simulated(p, seed=seed, steps=1500)
        with_cal.append(metrics(run_estimator("dead_reckoning", log, cal_cfg), log))
        plain.append(metrics(run_estimator("dead_reckoning", log, _config()), log))
    nees = np.mean([m["nees_position_mean"] for m in with_cal])
    nees0 = np.mean([m["nees_position_mean"] for m in plain])
    assert 1.0 <= nees <= 4.0, nees  # 1.54 (median 0.78: heavy-tailed across robots)
    assert nees0 > 4.0 * nees, nees0  # 89
    for a, b in zip(with_cal, plain, strict=True):
        assert a["ate_rmse_m"] == b["ate_rmse_m"]


@pytest.mark.parametrize(
    "opts, match",
    [
        ({"odometry_calibration": True, "odometry_calibration_sigma": [0.05]}, "3 prior sigmas"),
        ({"odometry_calibration": True, "odometry_calibration_walk": [0.0] * 3}, "walk"),
    ],
)
def test_bad_declarations_are_config_errors(opts, match):
    log = _simulated((1.0, 1.0, 0.0), seed=3, steps=50)
    with pytest.raises(ConfigError, match=match):
        run_estimator("dead_reckoning", log, _config(**opts))


def test_unsupported_drive_is_a_config_error_naming_the_key():
    cfg = RunConfig(
        log="sim",
        robot={"drive": "twist"},
        estimator="dead_reckoning",
        options={"dead_reckoning": {"odometry_calibration": True}},
        source="twist.yaml",
    )
    log = SensorLog(
        "sim",
        {"cmd_vel": Stream("cmd_vel", "sim", np.arange(5.0), ("v", "w"), np.ones((5, 2)))},
        {},
    )
    with pytest.raises(ConfigError, match="odometry calibration supports") as info:
        run_estimator("dead_reckoning", log, cfg)
    assert info.value.key == "options.dead_reckoning.odometry_calibration_sigma"


def test_plaza2_with_the_plaza1_default_prior():
    """The Plaza1 dead-reckoning config with only ``odometry_calibration: true`` added (the
    prior every Plaza1 filter config declares, the graph's defaults: chosen without Plaza2).
    Figures in docs/filters.md ("Dead reckoning and systematic errors")."""
    from odofuse.io.loader import load_log

    base = load_config(PACKAGE / "default_configs" / "plaza1-dead_reckoning.yaml")
    # the prior off explicitly (since issue 25 the default auto turns it on: ranges are fused)
    base = dataclasses.replace(base, options={"dead_reckoning": {"odometry_calibration": False}})
    cal = dataclasses.replace(base, options={"dead_reckoning": {"odometry_calibration": True}})
    auto = load_config(PACKAGE / "default_configs" / "plaza1-dead_reckoning.yaml")
    out = {}
    for name in ("builtin:plaza1", "builtin:plaza2"):
        log = load_log(name)
        m0 = metrics(run_estimator("dead_reckoning", log, dataclasses.replace(base, log=name)), log)
        m1 = metrics(run_estimator("dead_reckoning", log, dataclasses.replace(cal, log=name)), log)
        m2 = metrics(run_estimator("dead_reckoning", log, dataclasses.replace(auto, log=name)), log)
        assert m1["ate_rmse_m"] == m0["ate_rmse_m"]
        assert m2["nees_position_mean"] == m1["nees_position_mean"]  # the default is the prior
        out[name] = m0["nees_position_mean"], m1["nees_position_mean"]
    assert out["builtin:plaza2"][0] > 30.0  # 38.6: the heading bias the white noise misses
    assert 1.0 <= out["builtin:plaza2"][1] <= 4.0  # 1.59 with the prior
    # Plaza1's own bias is far smaller than the prior: underconfident (0.32 -> 0.015).
    assert out["builtin:plaza1"][1] < out["builtin:plaza1"][0]


def test_several_wheels_per_side_keep_the_poses_and_widen_the_covariance():
    """With two wheels a side the calibration term acts on every wheel of a side (it once
    read inputs 0 and 1, left1 and left2, as left and right): the poses are the plain run's
    and the covariance only grows."""
    t = np.arange(50) * 0.1
    wheels = np.cumsum(np.ones((50, 4)) * [1.0, 1.0, 1.1, 1.1], axis=0) * 0.1
    names = ("left1", "left2", "right1", "right2")
    log = SensorLog("sim", {"wheels": Stream("wheels", "sim", t, names, wheels)}, {})
    robot = {"drive": "differential", "wheel_radius": 0.1, "track_width": 0.5}
    plain = RunConfig(
        log="sim",
        robot={**robot, "wheels_per_side": 2},
        estimator="dead_reckoning",
        source="four.yaml",
    )
    cal = dataclasses.replace(plain, options={"dead_reckoning": {"odometry_calibration": True}})
    r0, r1 = (run_estimator("dead_reckoning", log, c).trajectory for c in (plain, cal))
    np.testing.assert_array_equal(r1.poses, r0.poses)
    grow = np.linalg.eigvalsh(r1.covariances - r0.covariances)
    assert grow.min() > -1e-12 and grow[-1].max() > 0
