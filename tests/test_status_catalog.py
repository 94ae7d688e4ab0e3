"""Issue 25, item 7: ``odofuse.status.CHECKS`` is the one place that lists every check behind
``status``; this keeps it true. Also the direct tests of the checks that had none of their
own (``gyro_wheels``, ``covariance_growth``, ``recovery``)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from odofuse.status import CHECKS

ROOT = Path(__file__).resolve().parents[1]


def _findings_made() -> dict[str, set[str]]:
    """Check name -> the odofuse modules that construct ``Finding("<name>", ...)``."""
    made: dict[str, set[str]] = {}
    for path in (ROOT / "odofuse").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Call) or not node.args:
                continue
            f = node.func
            if getattr(f, "id", getattr(f, "attr", None)) != "Finding":
                continue
            first = node.args[0]
            assert isinstance(first, ast.Constant), f"{path}:{node.lineno}: a computed check name"
            rel = path.relative_to(ROOT / "odofuse").as_posix()
            made.setdefault(first.value, set()).add(rel)
    return made


def test_every_finding_the_code_makes_is_in_the_catalog_where_it_is_made():
    made = _findings_made()
    listed = {c.name: set(c.raised_in) for c in CHECKS}
    assert len(listed) == len(CHECKS), "a check is listed twice"
    assert set(made) == set(listed), set(made) ^ set(listed)
    for name, modules in made.items():
        assert modules == listed[name], (name, modules, listed[name])


def test_every_check_names_a_test_that_exercises_it():
    for c in CHECKS:
        assert c.tests, c.name
        for t in c.tests:
            text = (ROOT / t).read_text(encoding="utf-8")
            # the check's name as a value, or its warning line's ``[name]``
            assert f'"{c.name}"' in text or f"[{c.name}]" in text, (c.name, t)


@pytest.mark.parametrize("estimator", ["ekf", "fixed_lag", "smoother", "isam2", "dead_reckoning"])
def test_every_share_of_the_budget_belongs_to_a_listed_check(estimator):
    from odofuse.config import config_from_dict
    from odofuse.io.log import SensorLog, Stream
    from odofuse.status.cross_check import alpha_budget

    t = np.linspace(0.0, 20.0, 50)
    z = np.zeros((50, 2))
    streams = {
        "odometry": Stream("odometry", "o.csv", t, ("ds", "dtheta"), z),
        "gyro": Stream("gyro", "g.csv", t, ("wz",), z[:, :1]),
        "gps": Stream("gps", "gps.csv", t, ("x", "y"), z),
    }
    cfg = config_from_dict(
        {
            "log": "x",
            "robot": {"drive": "increments"},
            "estimator": estimator,
            "sensors": {"gyro": {"sigma": 0.01}, "gps": {"sigma": 1.0}},
        },
        "c.yaml",
    )
    budget = alpha_budget(cfg, SensorLog("log", streams))
    counted = {k for c in CHECKS for k in c.budget}
    keys = {k.split(":")[0] for k in budget["checks"]}
    assert keys and keys <= counted, keys - counted
    assert budget["total"] <= budget["alpha_run"] and not budget["overspent"]


# ------------------------------------------------------- checks without a test of their own
def test_gyro_wheels_is_quiet_on_agreeing_sensors_and_names_a_slip():
    from odofuse.declarations import DeadReckoningOptions
    from odofuse.status.pose_checks import gyro_wheel_findings

    rng = np.random.default_rng(11)
    opts = DeadReckoningOptions()
    t = np.arange(0.0, 60.0 + 1e-9, 0.02)
    rate = 0.3 * np.sin(0.2 * t[:-1])  # rad/s
    var = np.full(t.size - 1, (2e-3) ** 2)
    wheels = rate * 0.02 + rng.normal(0.0, 2e-3, t.size - 1)
    gyro_wz = rate + rng.normal(0.0, 0.01, t.size - 1)
    assert gyro_wheel_findings(t, wheels, var, t[:-1], gyro_wz, 0.01, opts) == []
    slipped = wheels.copy()
    slipped[(t[:-1] >= 30.0) & (t[:-1] < 30.5)] += 0.3 / 25  # the wheels add 0.3 rad
    (f,) = gyro_wheel_findings(t, slipped, var, t[:-1], gyro_wz, 0.01, opts)
    assert f.check == "gyro_wheels" and f.degrades and f.sensor == "gyro"
    assert f.t_start <= 30.0 < f.t_end and f.figure == pytest.approx(-0.3, abs=0.05)


def test_covariance_growth_names_where_the_position_sigma_took_off():
    from odofuse.declarations import EkfOptions
    from odofuse.status.pose_checks import covariance_health

    t = np.arange(100.0)
    P = np.tile(np.diag([0.01, 0.01, 1e-4]), (100, 1, 1))
    assert covariance_health(t, P, EkfOptions()) == []
    P[60:, :2, :2] *= np.logspace(0, 5, 40)[:, None, None]  # sigma up 316-fold
    (f,) = covariance_health(t, P, EkfOptions())
    assert f.check == "covariance_growth" and f.t_end == 99.0
    assert f.figure == pytest.approx(10**2.5, rel=1e-6)


def test_recovery_is_reported_after_a_rejection_run():
    from odofuse.declarations import EkfOptions
    from odofuse.status.monitors import FilterMonitor

    class Gps:
        dim, gate = 2, 0.999

    mon = FilterMonitor(EkfOptions(), {"gps": Gps()})
    for k in range(10):
        assert not mon.observe("gps", float(k), True, 2.0)
    due = [mon.observe("gps", 10.0 + k, False, 500.0) for k in range(5)]
    assert due == [False] * 4 + [True]  # reject_run (5) in a row: the filter re-opens
    mon.recovered("gps", 1e3)
    (rec,) = [f for f in mon.stream_findings((0.0, 15.0)) if f.check == "recovery"]
    assert rec.sensor == "gps" and rec.t_start == 10.0 and rec.t_end == 14.0
    assert rec.figure == 1.0 and "x1e+03" in rec.message
