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
    (constant bias: fixed-lag NEES 29.0, iSAM2 57.9, both ``ok``)."""
    log, cfg = seed41
    m = ts.run(log, cfg, estimator)
    assert m["nees_position_mean"] < ts.HOLD_NEES, m["nees_position_mean"]
    assert np.isfinite(m["extra"]["calibration"]["gyro_bias"])
    assert m["status"] == "ok", m["warnings"]


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
