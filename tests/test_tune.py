"""``odofuse tune``: noise learned from the log by innovation likelihood, never from ground truth.

Simulated robots with known true noise (seeded): the learned values are within 30 % of the
truth and the tuned config is as accurate as the one with the true values. The ground-truth
tests tune a log folder whose ``groundtruth.csv`` is corrupt, absent or intact: same result.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from odofuse import tune as T
from odofuse.config import config_from_dict, load_config
from odofuse.errors import ConfigError, InputError
from odofuse.estimators import run_estimator
from odofuse.evaluation import metrics
from odofuse.teaching.scenario import scenario_from_dict
from odofuse.teaching.simlog import run_config, to_sensor_log, write_log
from odofuse.teaching.simulate import simulate

DIFF = {"drive": "differential", "wheel_radius": 0.04, "track_width": 0.235}
MECANUM = {"drive": "mecanum4", "wheel_radius": 0.05, "half_length": 0.2, "half_width": 0.2}
GPS = {"gps": {"sigma": 0.5, "rate": 1.0}}
COMPASS = {"compass": {"sigma": 0.02, "rate": 2.0}}
RANGES = {"ranges": {"sigma": 0.2, "rate": 2.0}}
K = 5e-4  # true wheel noise, m^2 per m rolled (every wheel)
#: robot -> (robot block, sensors, the two keys learned)
ROBOTS = {
    "differential_gps": (DIFF, {**GPS, **COMPASS}, ("motion.k", "sensors.gps.sigma")),
    "mecanum_compass": (MECANUM, {**GPS, **COMPASS}, ("motion.k", "sensors.compass.sigma")),
    "differential_ranges": (DIFF, {**RANGES, **COMPASS}, ("motion.k", "sensors.ranges.sigma")),
}
BEACONS = [[1, 0.0, 6.0], [2, 0.0, -6.0], [3, 8.0, 0.0], [4, -8.0, 0.0]]


def _sim(robot, sensors, seed=1, laps=1):
    sc = {
        "seed": seed,
        "dt": 0.2,
        "robot": robot,
        "path": {"kind": "figure_eight", "radius": 3.0, "speed": 0.4, "laps": laps},
        "nonsystematic": {"k": K},
        "sensors": sensors,
        "beacons": BEACONS,
    }
    return simulate(scenario_from_dict(sc, "<tune test>"))


def _true_raw(sim) -> dict:
    raw = run_config(sim, "ekf")
    raw.pop("output")
    raw["motion"] = {"integrator": "exact", "k": K}  # one k for every wheel, the true one
    return raw


def _rmse(raw, log) -> float:
    return metrics(run_estimator("ekf", log, config_from_dict(raw, "<tune test>")), log)[
        "ate_rmse_m"
    ]


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_learned_noise_within_30_percent_of_the_truth(name):
    robot, sensors, keys = ROBOTS[name]
    sim = _sim(robot, sensors)
    log = to_sensor_log(sim)
    raw = _true_raw(sim)
    truth = np.array([T.get_value(raw, k) for k in keys])
    start = T.set_values(raw, keys, truth * [3.0, 2.0])  # a user's guess, 3x and 2x off
    res = T.tune(
        config_from_dict(start, "<tune test>"),
        start,
        log,
        keys,
        uncertainty=name == "differential_gps",
        progress=lambda line: None,
    )
    assert res.stopped == "converged"
    ratio = np.array(res.values) / truth
    assert np.all(np.abs(ratio - 1.0) < 0.30), ratio
    # as accurate as the true noise (the best a hand tuner with ground truth could aim for)
    assert _rmse(res.raw, log) <= 1.1 * _rmse(raw, log)
    # the held-out last third fits better than with the starting guess
    h = res.heldout
    assert h["learned"]["updates"] > 50
    assert h["learned"]["mean_loglik"] > h["start"]["mean_loglik"]
    assert res.fit_loglik >= res.start_fit_loglik
    if name == "differential_gps":  # the inverse-Hessian 1-sigma covers the truth (3 sigma)
        assert all(s is not None and s > 0 for s in res.log_sigma)
        assert np.all(np.abs(np.log(ratio)) < 3.0 * np.array(res.log_sigma))


def _folder(tmp_path: Path, name: str, sim) -> Path:
    folder = tmp_path / name
    write_log(sim, folder)
    return folder


def test_tune_never_reads_ground_truth(tmp_path, capsys):
    from odofuse.cli import main
    from odofuse.io.loader import load_log_for

    sim = _sim(DIFF, GPS, seed=5)
    corrupt, absent, intact = (_folder(tmp_path, n, sim) for n in ("corrupt", "absent", "intact"))
    (corrupt / "groundtruth.csv").write_bytes(b"t,x,y,theta\n1,nan,\xff,oops\n")
    (absent / "groundtruth.csv").unlink()
    with pytest.raises(InputError):  # the file really is unreadable
        load_log_for(load_config(corrupt / "config.yaml"))
    keys = ["motion.k_l", "sensors.gps.sigma"]
    kw = {"max_evaluations": 12, "uncertainty": False, "progress": lambda line: None}
    out = tmp_path / "tuned.yaml"
    argv = ["tune", str(corrupt / "config.yaml"), "-o", str(out), "--params", *keys]
    assert main([*argv, "--max-seconds", "0"]) == 0  # the start values only: time bound
    printed = capsys.readouterr()
    assert "stopped: time bound" in printed.out and "tuned config" in printed.out
    assert "tune: run    1" in printed.err  # the progress line
    results = [T.tune_config(f / "config.yaml", None, keys, **kw)[0] for f in (corrupt, absent)]
    results.append(T.tune_config(intact / "config.yaml", tmp_path / "t.yaml", keys, **kw)[0])
    for r in results:
        assert r.values == results[0].values and r.heldout == results[0].heldout
    assert results[0].values != results[0].start  # it did learn something
    cli = load_config(out)
    assert cli.estimator == "ekf" and Path(cli.log) == corrupt
    text = out.read_text()
    assert text.startswith("# Made by `odofuse tune") and "ground truth was not read" in text
    assert "maximised: EKF innovation log-likelihood" in text and "held-out" in text


def test_bounds_and_bad_keys():
    sim = _sim(DIFF, GPS, seed=2)
    log = to_sensor_log(sim)
    raw = _true_raw(sim)
    cfg = config_from_dict(raw, "<tune test>")
    quiet = {"progress": lambda line: None}
    res = T.tune(cfg, raw, log, ["motion.k"], max_seconds=0.0, **quiet)
    assert res.stopped == "time bound" and res.values == res.start and res.evaluations == 1
    assert res.log_sigma == (None,)
    res = T.tune(cfg, raw, log, ["motion.k"], max_evaluations=3, **quiet)
    assert res.stopped == "evaluation bound" and res.evaluations == 3
    assert T.default_keys(raw) == ["motion.k", "sensors.gps.sigma"]
    for key, what in [
        ("motion.k[3]", "motion.k[3]"),
        ("sensors.lidar.sigma", "sensors.lidar.sigma"),
        ("motion.var_rate", "motion.var_rate"),  # absent: nothing to start from
        ("not a key", "not a key"),
    ]:
        with pytest.raises(ConfigError, match=re.escape(what)):
            T.tune(cfg, raw, log, [key], **quiet)
    with pytest.raises(ConfigError, match="fit-fraction"):
        T.tune(cfg, raw, log, ["motion.k"], fit_fraction=1.0, **quiet)


def test_criterion_is_the_gaussian_prediction_error_decomposition():
    sim = _sim(DIFF, GPS, seed=3)
    log = to_sensor_log(sim)
    cfg = config_from_dict(_true_raw(sim), "<tune test>")
    rec = T.innovations(log, cfg)
    assert {r[0] for r in rec} == {"gps"} and all(r[4] == 2 for r in rec)
    assert len(rec) == len(log.streams["gps"])  # one entry per row
    total, n = T.loglik(rec)
    # log N(y; 0, S) summed: -(log det(2 pi S) + y^T S^-1 y) / 2, with S = H P H^T + R >= R
    assert n == len(rec) and math.isclose(total, -0.5 * sum(r[2] + r[3] for r in rec))
    logdet_R = 2.0 * math.log(2.0 * math.pi * 0.5**2)
    assert all(r[2] >= logdet_R - 1e-9 for r in rec)
    assert T.loglik(rec, t_min=50.0)[1] == np.count_nonzero(log.streams["gps"].t > 50.0)
    # with the true noise the innovations are consistent: NIS per dimension ~ 1
    assert 0.7 < T.heldout_summary(rec, -math.inf)["nis"]["gps"] < 1.3


@pytest.mark.parametrize("name", ["differential_gps", "differential_ranges"])
def test_compiled_criterion_equals_the_python_one(name):
    # the compiled path reads S from rejected probe readings: same records as the Python EKF
    robot, sensors, _ = ROBOTS[name]
    sim = _sim(robot, sensors, seed=4)
    log = to_sensor_log(sim)
    raw = _true_raw(sim)
    raw["sensors"]["gps" if "gps" in raw["sensors"] else "ranges"]["sigma"] *= 0.5  # rejects
    cfg = config_from_dict(raw, "<tune test>")
    fast = T.compiled_innovations(log, cfg)
    slow = T.python_innovations(log, cfg)
    assert fast is not None and len(fast) == len(slow) > 100
    fast, slow = (sorted(r, key=lambda r: (r[1], r[0])) for r in (fast, slow))
    assert {r[0] for r in fast} == set(sensors)
    assert any(not r[5] for r in slow)  # some readings gated out
    for a, b in zip(fast, slow, strict=True):
        assert a[0] == b[0] and a[1] == b[1] and a[4] == b[4] and a[5] == b[5]
        assert math.isclose(a[2], b[2], rel_tol=1e-9, abs_tol=1e-9)
        assert math.isclose(a[3], b[3], rel_tol=1e-9, abs_tol=1e-9)
    # a gyro moves its clone state even when rejected: no probes, the Python path
    sim = _sim(robot, {**sensors, "gyro": {"sigma": 0.01, "rate": 5.0}}, seed=4)
    raw = _true_raw(sim)
    assert "gyro" in raw["sensors"]
    assert T.compiled_innovations(to_sensor_log(sim), config_from_dict(raw, "<t>")) is None


def test_a_noise_the_log_does_not_want_is_reported_at_its_lower_bound():
    # the simulated wheels have no per-second noise: its learned value goes to start / SPAN
    sim = _sim(DIFF, GPS, seed=2)
    log = to_sensor_log(sim)
    raw = _true_raw(sim)
    raw["motion"]["var_rate"] = 1.0e-3  # rad^2 per s per wheel, none in the simulation
    keys = ["motion.var_rate", "sensors.gps.sigma"]
    res = T.tune(config_from_dict(raw, "<tune test>"), raw, log, keys, progress=lambda s: None)
    assert res.stopped == "converged" and res.at_bound == ("lower", "")
    assert res.values[0] <= 1.0e-3 / T.SPAN * math.exp(T.HESSIAN_STEP)
    assert res.log_sigma[0] is None and res.log_sigma[1] is not None  # the other's Hessian
    assert abs(res.values[1] / 0.5 - 1.0) < 0.3
    assert any("motion.var_rate" in line and "lower bound" in line for line in T.report_lines(res))
