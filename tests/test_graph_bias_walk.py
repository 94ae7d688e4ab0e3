"""A walking gyro bias in the graph back ends (issue 10): one bias variable per keyframe
interval, chained by GTSAM ``BetweenFactorVector`` with sigma ``bias_walk * sqrt(tau)``.

The walk is the scenario's declared truth (``bias_walk: 2e-4`` rad/s/sqrt(s) of
``gyro_bias_walk``, what its gyro's datasheet says); nothing here is tuned on ground truth.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

import odofuse.teaching.trust_scenarios as ts
from odofuse import se2
from odofuse.estimators.graph.factors import Factors
from odofuse.estimators.graph.problem import build_problem

pytest.importorskip("gtsam")


def _walk_log(seed: int, laps=None):
    """``(log, config)`` of ``gyro_bias_walk`` at ``seed`` as ``odofuse simulate`` writes it."""
    from odofuse.config import load_config
    from odofuse.io.loader import load_log_for
    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import write_log
    from odofuse.teaching.simulate import simulate

    over, _ = ts.SIMULATED["gyro_bias_walk"]
    d = ts._merge(ts._BASE, over)
    if laps is not None:
        d = ts._merge(d, {"path": {"laps": laps}})
    sim = simulate(scenario_from_dict(d, "gyro_bias_walk"), seed=seed)
    with tempfile.TemporaryDirectory() as folder:
        write_log(sim, folder)
        cfg = load_config(Path(folder) / "config.yaml")
        return load_log_for(cfg), cfg


def _with_walk(cfg, walk: float):
    sensors = dict(cfg.sensors)
    sensors["gyro"] = dataclasses.replace(sensors["gyro"], bias_walk=float(walk))
    return dataclasses.replace(cfg, sensors=sensors)


#: rad/s/sqrt(s), the scenario's declared walk (its gyro's datasheet figure)
WALK = ts.SIMULATED["gyro_bias_walk"][0]["sensors"]["gyro"]["bias_walk"]


@pytest.fixture(scope="module")
def seed41():
    log, cfg = _walk_log(41)
    return log, _with_walk(cfg, WALK)


def test_no_walk_is_one_constant_bias_variable(seed41):
    log, cfg = seed41
    problem = build_problem(log, _with_walk(cfg, 0.0), "smoother")
    assert problem.bias_walk == {}
    key = problem.calib["gyro_bias"][0]
    assert problem.final_key("gyro_bias") == key
    assert all(problem.bias_key("gyro_bias", j) == key for j in range(len(problem.kt) - 1))


def test_walking_bias_is_a_chain_of_between_factors(seed41):
    import gtsam

    log, cfg = seed41
    problem = build_problem(log, cfg, "smoother")
    assert problem.bias_walk == {"gyro_bias": WALK}
    fac = Factors(problem)
    graph, values = fac.static()
    for i, pose in enumerate(problem.dead_reckoning()):
        fac.keyframe(i, gtsam.Pose2(*pose), graph, values)
    K = len(problem.kt)
    keys = [problem.bias_key("gyro_bias", j) for j in range(K - 1)]
    assert len(set(keys)) == K - 1 and all(values.exists(k) for k in keys)
    chain = [graph.at(n) for n in range(graph.size())]
    chain = [f for f in chain if isinstance(f, gtsam.BetweenFactorVector)]
    assert len(chain) == K - 2
    for j, f in enumerate(chain, start=1):
        assert list(f.keys()) == [keys[j - 1], keys[j]]
        tau = 0.5 * (problem.kt[j + 1] - problem.kt[j - 1])
        sigma = f.noiseModel().sigmas()[0]
        assert sigma == pytest.approx(WALK * math.sqrt(tau), rel=1e-12)
    # each gyro increment uses the segment of its own keyframe interval
    inc = problem.gyro["gyro"]
    for _stream, n, f in fac.gyro_created[:: max(1, len(fac.gyro_created) // 7)]:
        assert keys[int(inc.interval[n])] in list(f.keys())
    assert problem.final_key("gyro_bias") == keys[-1]


def test_walking_bias_beats_the_constant_one_on_nees(seed41):
    """Seed 41, full length: the constant bias is silently overconfident (position NEES 57.7,
    ``ok``, measured before this change); the walking one holds."""
    log, cfg = seed41
    const = ts.run(log, _with_walk(cfg, 0.0), "smoother")
    walk = ts.run(log, cfg, "smoother")
    assert const["nees_position_mean"] > ts.HOLD_NEES  # the silent failure of issue 10
    assert walk["nees_position_mean"] < ts.HOLD_NEES
    assert walk["nees_position_mean"] < 0.2 * const["nees_position_mean"]
    assert walk["ate_rmse_m"] < const["ate_rmse_m"]
    # the reported bias is the final segment's; the first one is reported apart
    cal, first = walk["extra"]["calibration"], walk["extra"]["calibration_walk"]["gyro_bias"]
    assert first["segments"] == walk["extra"]["keyframes"] - 1
    assert first["bias_walk"] == WALK
    assert abs(cal["gyro_bias"] - first["first"]) > 0.0
    assert 0.0 < walk["extra"]["calibration_sigma"]["gyro_bias"] < 0.01  # below the prior


@pytest.mark.parametrize("estimator", ["fixed_lag", "isam2"])
def test_incremental_smoothers_take_the_walking_bias(seed41, estimator):
    """Fixed-lag marginalises the old segments with their keyframes; both hold on seed 41
    (constant bias: fixed-lag NEES 29.0, iSAM2 57.9, both ``ok``), and their own checks say
    ``ok``. Through ``odofuse run`` the second opinion judged fixed-lag here (0.140 m against
    the smoother's 0.103 m, p_fail 0.13 at predicted ratio 1.41) a failure under issue 10's
    rule (docs/trust.md 6.3); since issue 25 that ratio is advice, and the run stays ``ok``:
    its covariance covers its departure from the smoother."""
    from odofuse.rundir import estimate

    log, cfg = seed41
    made = estimate(ts.run_config(cfg, estimator, check=False), log)
    alone = ts.run(log, cfg, estimator, check=False, estimated=made)
    assert alone["nees_position_mean"] < ts.HOLD_NEES, alone["nees_position_mean"]
    assert np.isfinite(alone["extra"]["calibration"]["gyro_bias"])
    assert alone["status"] == "ok", alone["warnings"]
    checked = ts.run(log, cfg, estimator, estimated=made)
    assert checked["cross_check"]["p_fail"] is not None, checked["cross_check"]
    assert checked["cross_check"]["departure_nees"] < checked["cross_check"]["nees_bound"]
    assert checked["status"] == "ok" and checked["warnings"] == [], checked["warnings"]


def test_simulate_writes_the_simulated_bias_walk():
    """``odofuse simulate``'s config states the simulated noise (gyro, GPS, range sigmas, the
    wheels' ``k``): the gyro's bias walk follows the same rule; without a walk the config is
    as before (no key)."""
    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import run_config
    from odofuse.teaching.simulate import simulate

    over, _ = ts.SIMULATED["gyro_bias_walk"]
    for walk in (WALK, 0.0):
        d = ts._merge(ts._merge(ts._BASE, over), {"path": {"laps": 1}})
        d = ts._merge(d, {"sensors": {"gyro": {"bias_walk": walk}}})
        gyro = run_config(simulate(scenario_from_dict(d)))["sensors"]["gyro"]
        assert gyro.get("bias_walk") == (walk or None)
        assert gyro["sigma"] == d["sensors"]["gyro"]["sigma"]


@pytest.mark.parametrize("estimator", ["smoother", "isam2", "fixed_lag"])
def test_two_walking_gyros_each_have_their_own_chain(seed41, estimator):
    """A second IMU ``gyro_2`` reading the first one's rates 0.02 rad/s lower (with noise of its
    own): two chains with distinct keys, and their final biases 0.02 rad/s apart."""
    from odofuse.io.log import Stream

    log, cfg = seed41
    g = log.streams["gyro"]
    rng = np.random.default_rng(5)
    wz2 = g["wz"] - 0.02 + rng.normal(0.0, 0.002, len(g))
    streams = {**log.streams, "gyro_2": Stream("gyro_2", "sim", g.t, ("wz",), wz2[:, None])}
    log2 = dataclasses.replace(log, streams=streams)
    cfg2 = dataclasses.replace(cfg, sensors={**cfg.sensors, "gyro_2": cfg.sensors["gyro"]})
    problem = build_problem(log2, cfg2, estimator)
    assert set(problem.bias_walk) == {"gyro_bias", "gyro_bias:gyro_2"}
    last = len(problem.kt) - 2
    assert problem.bias_key("gyro_bias", last) != problem.bias_key("gyro_bias:gyro_2", last)
    m = ts.run(log2, cfg2, estimator)
    cal = m["extra"]["calibration"]
    assert abs(cal["gyro_bias"] - cal["gyro_bias:gyro_2"] - 0.02) < 2e-3, cal
    assert m["nees_position_mean"] < ts.HOLD_NEES


def _walk_with_truth(seed: int):
    """A one-lap ``gyro_bias_walk`` log (no systematic wheel errors), its config, the simulated
    bias per gyro row and the true heading: ``(log, config, (t_gyro, bias), (t, heading))``.

    The simulator does not return the bias it drew; the same scenario with a noise-free gyro
    (``sigma: 0``) draws the same random numbers (a zero-sigma normal still consumes its
    draws), so its gyro reads the true rate plus the bias, and the truth's heading gives the
    rate. The config is the one ``odofuse simulate`` writes, its initial sigma set to 1e-6:
    the simulated robot starts exactly at the stated pose (a declared 0.01 rad that is never
    realised makes every heading look over-covered, see docs/graph.md).
    """
    from odofuse.config import load_config
    from odofuse.io.loader import load_log_for
    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import write_log
    from odofuse.teaching.simulate import simulate

    over, _ = ts.SIMULATED["gyro_bias_walk"]
    d = ts._merge(ts._BASE, over)
    d = ts._merge(d, {"path": {"laps": 1}, "systematic": {"E_d": 1.0, "E_b": 1.0}})
    sim = simulate(scenario_from_dict(d, "walk"), seed=seed)
    quiet = simulate(scenario_from_dict(ts._merge(d, {"sensors": {"gyro": {"sigma": 0.0}}})), seed)
    assert np.array_equal(sim.truth, quiet.truth)
    g = quiet.streams["gyro"]
    heading = np.unwrap(sim.truth[:, 2])
    step = np.searchsorted(sim.t, g.t - 1e-9)  # a gyro row per simulation step here
    rate = (heading[step] - heading[step - 1]) / (sim.t[step] - sim.t[step - 1])
    with tempfile.TemporaryDirectory() as folder:
        write_log(sim, folder)
        cfg = load_config(Path(folder) / "config.yaml")
        log = load_log_for(cfg)
    cfg = dataclasses.replace(cfg, initial=dataclasses.replace(cfg.initial, sigma=(1e-6,) * 3))
    return log, cfg, (g.t, g.values[:, 0] - rate), (sim.t, heading)


#: Monte Carlo seeds; none of them was used while looking for the cause of the low NEES
MC_SEEDS = range(500, 516)


@pytest.fixture(scope="module")
def monte_carlo():
    """Per seed: the final segment's bias and the final heading, each as (error, sigma), and
    the true segment means' steps over their modelled sigmas."""
    from odofuse.estimators.graph.solvers import run_smoother

    bias, heading, steps = [], [], []
    for seed in MC_SEEDS:
        log, cfg, (tg, b), (t, theta) = _walk_with_truth(seed)
        problem = build_problem(log, cfg, "smoother")
        kt = problem.kt
        means = np.array([b[(tg > kt[j]) & (tg <= kt[j + 1])].mean() for j in range(len(kt) - 1)])
        sig = np.array([problem.bias_step_sigma("gyro_bias", j) for j in range(1, len(kt) - 1)])
        steps.append(np.diff(means) / sig)
        res = run_smoother(log, cfg)
        cal, sd = res.extra["calibration"], res.extra["calibration_sigma"]
        bias.append((cal["gyro_bias"] - means[-1], sd["gyro_bias"]))
        traj = res.trajectory
        err = float(se2.wrap(traj.poses[-1, 2] - np.interp(traj.t[-1], t, theta)))
        heading.append((err, math.sqrt(traj.covariances[-1][2, 2])))
    return bias, heading, np.concatenate(steps)


def _chi2_band(n: int) -> tuple[float, float]:
    from scipy.stats import chi2

    return float(chi2.ppf(0.001, n)), float(chi2.ppf(0.999, n))


def test_walking_bias_marginal_is_consistent_monte_carlo(monte_carlo):
    """Issue 10: the reported sigma of the walking bias (its final segment, what ``metrics.json``
    gives) and of the final heading cover the errors over 16 seeded runs: the sum of squared
    normalised errors lies in the chi-square(16) 99.8 % band (one independent error per run).
    Measured: bias 11.2, heading 12.6 (band 3.9-39.3); the walk left out of the model: bias
    148. A walk counted twice is too mild for this band (7.3-8.6): the next test catches it."""
    bias, heading, _ = monte_carlo
    lo, hi = _chi2_band(len(MC_SEEDS))
    for name, pairs in (("bias", bias), ("heading", heading)):
        z2 = sum((e / s) ** 2 for e, s in pairs)
        assert lo < z2 < hi, (name, z2, (lo, hi))


def test_walk_between_sigma_matches_the_simulated_walk(monte_carlo):
    """The between factors' sigma ``bias_walk * sqrt(tau)`` against the steps of the true
    segment means: a Brownian bias averaged over two adjacent intervals of lengths A and B
    steps by variance ``q (A + B) / 3``, the model says ``q (A + B) / 2`` (the centre spacing,
    right for the walk over many intervals), so the normalised steps' mean square is 2/3, not
    1 (docs/graph.md: this costs the bias marginal 2-6 % of variance). Measured 0.69; a sigma
    with the walk counted twice gives 1/3 (measured 0.35), one of the per-sample walk (0.02 s)
    ~33."""
    _, _, steps = monte_carlo
    ms = float(np.mean(steps**2))
    assert 0.55 < ms < 0.8, ms
