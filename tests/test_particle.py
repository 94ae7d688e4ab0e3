"""Particle filter: low-variance resampling, motion sampling, reweighting, seeding, Plaza1."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from odofuse.config import RunConfig
from odofuse.estimators.particle import ParticleBackend, low_variance_resample
from odofuse.estimators.particle import run as run_pf
from odofuse.measurements import BeaconRange, GpsPosition
from odofuse.motion import motion_model_from_config


def _motion(k=(1e-2, 1e-3)):
    cfg = RunConfig(
        log="x", robot={"drive": "increments"}, motion={"integrator": "exact", "k": list(k)}
    )
    return motion_model_from_config(cfg)


def test_low_variance_resampling_copies_floor_or_ceil_of_n_w():
    rng = np.random.default_rng(0)
    w = rng.uniform(size=50)
    w /= w.sum()
    for _ in range(20):
        idx = low_variance_resample(w, rng)
        counts = np.bincount(idx, minlength=50)
        assert counts.sum() == 50
        assert np.all(counts >= np.floor(50 * w) - 1e-9)
        assert np.all(counts <= np.ceil(50 * w) + 1e-9)
    # Uniform weights: every particle exactly once, in order.
    np.testing.assert_array_equal(low_variance_resample(np.full(8, 1 / 8), rng), np.arange(8))
    # A single dominant weight takes every pointer.
    np.testing.assert_array_equal(low_variance_resample(np.array([0, 0, 1.0, 0]), rng), [2] * 4)


def test_predicted_cloud_matches_the_ekf_moments():
    from odofuse.estimators.ekf import EkfBackend

    model = _motion()
    x0, P0 = np.array([1.0, 2.0, 0.5]), np.diag([0.01, 0.02, 0.001])
    pf = ParticleBackend(model, {}, x0, P0, np.zeros(3), {"particles": 40000, "seed": 1})
    ekf = EkfBackend(model, {}, x0, P0, np.zeros(3))
    for _ in range(20):
        u = np.array([0.2, 0.02])
        pf.predict(u, 0.1)
        ekf.predict(u, 0.1)
    # Monte-Carlo error of the mean ~ sqrt(P / N) ~ 1e-3; the EKF's linearisation error is
    # second order in the small heading spread.
    np.testing.assert_allclose(pf.mean(), ekf.mean(), atol=3e-3)
    np.testing.assert_allclose(pf.cov(), ekf.cov(), rtol=0.05, atol=2e-4)


def test_update_weights_are_the_gaussian_likelihood():
    model = _motion()
    gps = GpsPosition("gps", 0.5, gate=None)
    pf = ParticleBackend(
        model,
        {"gps": gps},
        np.zeros(3),
        np.eye(3) * 0.25,
        np.zeros(3),
        {"particles": 200, "seed": 2, "resample_threshold": 0.0},
    )
    X = pf.X.copy()
    z = np.array([0.3, -0.1])
    accepted, _ = pf.update(gps, {"x": z[0], "y": z[1]})
    assert accepted
    logl = -0.5 * np.sum((z - X[:, :2]) ** 2, axis=1) / 0.25
    w = np.exp(logl - logl.max())
    np.testing.assert_allclose(pf.w, w / w.sum(), rtol=1e-12)


def test_resampling_happens_when_the_effective_size_drops():
    model = _motion()
    gps = GpsPosition("gps", 0.05, gate=None)
    pf = ParticleBackend(
        model, {"gps": gps}, np.zeros(3), np.eye(3), np.zeros(3), {"particles": 500, "seed": 3}
    )
    pf.update(gps, {"x": 0.0, "y": 0.0})
    assert pf.resamples == 1
    np.testing.assert_allclose(pf.w, 1 / 500)
    assert np.hypot(*pf.mean()[:2]) < 0.1


def test_gate_uses_the_cloud_innovation():
    model = _motion()
    gps = GpsPosition("gps", 0.1, gate=0.999)
    pf = ParticleBackend(
        model,
        {"gps": gps},
        np.zeros(3),
        np.eye(3) * 0.01,
        np.zeros(3),
        {"particles": 300, "seed": 4},
    )
    w = pf.w.copy()
    accepted, nis = pf.update(gps, {"x": 10.0, "y": 0.0})
    assert not accepted and nis > 13.8
    np.testing.assert_array_equal(pf.w, w)


def test_bimodal_prior_resolved_by_a_measurement():
    # Two hypotheses 10 m apart (a symmetric start a unimodal filter cannot hold);
    # a range to a beacon near one of them selects it.
    model = _motion()
    beacon = BeaconRange("ranges", 0.2, landmarks={0: np.array([12.0, 0.0])}, gate=None)
    pf = ParticleBackend(
        model,
        {"r": beacon},
        np.zeros(3),
        np.eye(3) * 0.01,
        np.zeros(3),
        {"particles": 2000, "seed": 5},
    )
    pf.X[1000:, 0] += 10.0
    assert abs(pf.mean()[0] - 5.0) < 0.1
    pf.update(beacon, {"id": 0, "range": 2.0})
    assert abs(pf.mean()[0] - 10.0) < 0.2


def test_seeded_runs_are_reproducible_and_snapshots_restore():
    from test_ekf import sim_config, simulate

    log, _ = simulate(6, steps=150)
    cfg = sim_config(estimator="particle", particles=300, seed=11)
    a, b = run_pf(log, cfg), run_pf(log, cfg)
    np.testing.assert_array_equal(a.trajectory.poses, b.trajectory.poses)
    c = run_pf(log, sim_config(estimator="particle", particles=300, seed=12))
    assert not np.array_equal(a.trajectory.poses, c.trajectory.poses)
    model = _motion()
    pf = ParticleBackend(
        model, {}, np.zeros(3), np.eye(3) * 0.01, np.zeros(3), {"particles": 100, "seed": 0}
    )
    snap = pf.snapshot()
    pf.predict(np.array([0.2, 0.01]), 0.1)
    first = pf.X.copy()
    pf.restore(snap)
    pf.predict(np.array([0.2, 0.01]), 0.1)
    np.testing.assert_array_equal(pf.X, first)


def test_simulated_run_is_accurate():
    from test_ekf import sim_config, simulate

    log, truth = simulate(8, steps=400)
    res = run_pf(log, sim_config(estimator="particle", particles=500, seed=0))
    err = np.hypot(*(res.trajectory.xy - truth[:, :2]).T)
    assert math.sqrt(np.mean(err**2)) < 0.3
    assert res.extra["particles"] == 500 and res.extra["resamples"] > 0


@pytest.mark.slow
def test_plaza1_particle_rmse_at_most_half_a_metre(monkeypatch):
    import pathlib

    from test_ekf import _plaza_rmse

    monkeypatch.chdir(pathlib.Path(__file__).resolve().parents[1])
    rmse, res, log = _plaza_rmse("particle")
    assert rmse <= 0.5


def test_liu_west_resampling_keeps_the_calibration_posterior_moments():
    model = _motion()
    m = BeaconRange("ranges", 0.3, landmarks={0: np.array([5.0, 0.0])}, calibrate=True)
    m = m.bind({"range_scale": 3, "range_offset": 4})
    x0 = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    P0 = np.diag([0.01, 0.01, 0.001, 0.05**2, 0.5**2])
    pf = ParticleBackend(
        model, {"r": m}, x0, P0, np.zeros(5), {"particles": 20000, "seed": 9, "roughening": 0.3}
    )
    rng = np.random.default_rng(1)
    w = rng.uniform(size=pf.N) * np.exp(-0.5 * ((pf.X[:, 3] - 1.02) / 0.03) ** 2)
    pf.w = w / w.sum()
    mean = pf.w @ pf.X[:, 3:]
    D = pf.X[:, 3:] - mean
    var = pf.w @ (D**2)
    unique_before = np.unique(pf.X[low_variance_resample(pf.w, np.random.default_rng(0)), 3]).size
    pf._resample()
    assert np.all(np.abs(pf.X[:, 3:].mean(axis=0) - mean) < 3 * np.sqrt(var / 2000))
    np.testing.assert_allclose(pf.X[:, 3:].var(axis=0), var, rtol=0.1)
    # Duplicates are spread again: every particle's scale is distinct.
    assert np.unique(pf.X[:, 3]).size == pf.N > unique_before


@pytest.mark.slow(seconds=11)  # four 1000-particle runs of a 94 s log (compiled): 10.4-10.5 s alone
def test_two_filter_seeds_agree_within_their_covariances():
    # docs/filters.md, "The calibration states' kernel": tuning log 5063 of
    # benchmarks/bench_particle_seeds.py (precise ranges, 1000 particles, the user's config).
    # Two seeds' positions differ by their Monte Carlo errors alone; at the Liu-West width of
    # 0.1 the cloud's calibration states settled on seed-dependent values (34.5 in the sum of
    # the covariances), at the default 0.3 they agree (0.046). No ground truth is read.
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_particle_seeds as bps
    import bench_status as bs

    from odofuse.declarations import ParticleOptions
    from odofuse.log_defaults import apply_log_defaults

    assert ParticleOptions().roughening == 0.3
    log, cfg, _ = bs.make_case(5063)
    # the tuning's config: k_theta_ds at its default (bench_status states 0 since session 46,
    # the simulator's; with it the two seeds disagree by 0.129 at 0.3 and 1.45 at 0.1)
    cfg = dataclasses.replace(cfg, motion=dataclasses.replace(cfg.motion, k_theta_ds=None))
    cfg, log = apply_log_defaults(cfg, log)
    assert bps.disagreement(cfg, log, {}) < 0.1
    assert bps.disagreement(cfg, log, {"roughening": 0.1}) > 10
