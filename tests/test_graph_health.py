"""The graph back end says when it failed (issue 10 item 4): findings, never a quiet ``ok``.

Every check runs without ground truth (:mod:`odofuse.status.graph_checks`); the tests
provoke each failure on a small simulated log and check that the run is ``degraded`` with a
warning naming the cause, and that a healthy run stays ``ok``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from graph_sim import simulated_run  # noqa: E402

from odofuse.estimators import run_estimator  # noqa: E402
from odofuse.estimators.graph.solvers import (  # noqa: E402
    levenberg_marquardt,
    marginal_covariances,
)
from odofuse.evaluation import metrics  # noqa: E402
from odofuse.io.log import Stream  # noqa: E402
from odofuse.status import graph_checks as health  # noqa: E402

X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L

SCENARIO = {
    "seed": 5,
    "dt": 0.02,
    "robot": {"drive": "differential", "wheel_radius": 0.04, "track_width": 0.235},
    "path": {"kind": "figure_eight", "radius": 3.0, "speed": 0.4, "laps": 1},
    "systematic": {"E_d": 1.002, "E_b": 1.01},
    "nonsystematic": {"k": 1.0e-5},
    "sensors": {"gps": {"sigma": 0.3, "rate": 1.0}},
}


def _run(estimator="smoother", options=None, sensors=None, scenario=SCENARIO, edit=None):
    log, cfg = simulated_run(scenario, 5, estimator, options, sensors)
    if edit is not None:
        log = edit(log)
    res = run_estimator(estimator, log, cfg)
    return res, metrics(res, log)


def _checks(m) -> set:
    return {f["check"] for f in m["findings"]}


@pytest.mark.parametrize("estimator", ["smoother", "isam2", "fixed_lag"])
def test_healthy_run_is_ok(estimator):
    res, m = _run(estimator)
    assert m["status"] == "ok", m["warnings"]
    assert m["ate_rmse_m"] < 0.3
    summary = res.extra["residuals"]
    assert set(summary) == {"wheels", "gps"}
    # a right noise model: median chi-square near its expectation, few beyond the 0.999 bound
    assert 0.25 < summary["gps"]["median_ratio"] < 4.0
    assert summary["gps"]["beyond_999"] < 0.05


def test_iteration_cap_is_degraded():
    _, m = _run(options={"max_iterations": 1})
    assert m["status"] == "degraded"
    assert any("iteration cap (1 iterations)" in w for w in m["warnings"]), m["warnings"]


def test_python_lm_iteration_cap_is_degraded():
    # odometry calibration makes the graph hold Python factors: odofuse's own LM loop
    res, m = _run(options={"max_iterations": 1, "odometry_calibration": True})
    assert res.extra["python_factors"] > 0
    assert any(w.startswith("[solver]") and "iteration cap" in w for w in m["warnings"])


def test_indeterminate_system_in_the_lm_loop_is_reported_not_raised():
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))

    def error(this, values, H):  # a factor whose Jacobian is not finite
        if H is not None:
            H[0] = np.array([[np.nan, 0.0, 0.0]])
        return np.array([values.atPose2(X(1)).x() - 1.0])

    noise = gtsam.noiseModel.Isotropic.Sigma(1, 0.1)
    g.add(gtsam.CustomFactor(noise, gtsam.KeyVector([X(1)]), error))
    v.insert(X(0), gtsam.Pose2())
    v.insert(X(1), gtsam.Pose2(0.5, 0.0, 0.0))
    out = levenberg_marquardt(g, v, {X(0): 3, X(1): 3})
    assert out.reason == "no_decrease" and out.indeterminate > 0
    (f,) = health.solver_findings("Levenberg-Marquardt", out.reason, out.iterations)
    assert f.degrades and "indeterminate" in f.message


def test_marginals_failure_is_regularised_and_reported():
    # a landmark seen by a single range: its tangential direction is not determined
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    g.add(gtsam.RangeFactor2D(X(0), L(0), 5.0, gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    v.insert(X(0), gtsam.Pose2())
    v.insert(L(0), gtsam.Point2(5.0 / np.sqrt(2), 5.0 / np.sqrt(2)))
    with pytest.raises(RuntimeError):
        gtsam.Marginals(g, v)
    cov, findings = marginal_covariances(g, v, [X(0), L(0)], {X(0): 3, L(0): 2})
    assert findings and findings[0].check == "covariance" and findings[0].degrades
    # the determined pose keeps its covariance; the landmark's free direction gets the prior's
    np.testing.assert_allclose(cov[X(0)], 0.01 * np.eye(3), rtol=1e-5, atol=1e-7)
    assert np.linalg.eigvalsh(cov[L(0)])[-1] > 1e3


def test_marginals_that_cholesky_refuses_are_taken_by_qr_exactly(monkeypatch):
    """When GTSAM's (Cholesky) ``Marginals`` calls a determined system indeterminate (a
    numerical failure: the information matrix squares the Jacobian's condition number), the
    covariances are QR's, equal to the true ones, and no finding is added."""
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    g.add(gtsam.RangeFactor2D(X(0), L(0), 5.0, gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    g.add(
        gtsam.BearingFactor2D(
            X(0), L(0), gtsam.Rot2(0.3), gtsam.noiseModel.Isotropic.Sigma(1, 0.05)
        )
    )
    v.insert(X(0), gtsam.Pose2(0.02, -0.01, 0.01))
    v.insert(L(0), gtsam.Point2(4.8, 1.5))
    truth = gtsam.Marginals(g, v)
    want = {k: truth.marginalCovariance(k) for k in (X(0), L(0))}

    def refuses(*args):
        raise RuntimeError("Indeterminate linear system detected (simulated)")

    monkeypatch.setattr(gtsam, "Marginals", refuses)
    cov, findings = marginal_covariances(g, v, [X(0), L(0)], {X(0): 3, L(0): 2})
    assert findings == []
    for k, c in want.items():
        np.testing.assert_allclose(cov[k], c, rtol=1e-9, atol=1e-14)


def test_a_damped_system_cholesky_refuses_is_solved_by_qr():
    """The Python LM's elimination (``solvers._solve_damped``): GTSAM's default first, QR
    when it raises, None when both fail or QR's step is not finite."""
    from odofuse.estimators.graph.solvers import _solve_damped

    g = gtsam.GaussianFactorGraph()
    g.add(
        gtsam.JacobianFactor(
            X(0),
            np.diag([2.0, 3.0, 4.0]),
            np.array([2.0, 3.0, 8.0]),
            gtsam.noiseModel.Unit.Create(3),
        )
    )
    ordering = gtsam.Ordering.Colamd(gtsam.VariableIndex(g))

    class Refusing:  # the default elimination raises as Cholesky's indeterminate system does
        def __init__(self, qr_fails=False, nan=False):
            self.qr_fails, self.nan = qr_fails, nan

        def optimize(self, order, function=None):
            if function is None or self.qr_fails:
                raise RuntimeError("Indeterminate linear system detected (simulated)")
            assert function is gtsam.EliminateQR
            if self.nan:
                bad = gtsam.GaussianFactorGraph()
                bad.add(
                    gtsam.JacobianFactor(
                        X(0), np.eye(3), np.full(3, np.nan), gtsam.noiseModel.Unit.Create(3)
                    )
                )
                return bad.optimize(order, function)
            return g.optimize(order, function)

    delta, refused = _solve_damped(g, ordering)
    np.testing.assert_allclose(delta.at(X(0)), [1.0, 1.0, 2.0])
    assert not refused
    delta, refused = _solve_damped(Refusing(), ordering)
    np.testing.assert_allclose(delta.at(X(0)), [1.0, 1.0, 2.0])
    assert refused
    # told Cholesky refused before: straight to QR, and no refusal of its own to report
    delta, refused = _solve_damped(Refusing(), ordering, cholesky=False)
    np.testing.assert_allclose(delta.at(X(0)), [1.0, 1.0, 2.0])
    assert not refused
    assert _solve_damped(Refusing(qr_fails=True), ordering) == (None, True)
    assert _solve_damped(Refusing(nan=True), ordering) == (None, True)


@pytest.mark.slow(seconds=16)  # Plaza2's range-only SLAM smoother through the CLI: 16 s
def test_plaza2_calibrated_slam_converges_with_its_covariances(tmp_path):
    """Before: ``[solver]`` (LM at its 100-iteration cap, graph error 315.23, still falling:
    Cholesky refused the damped system at lambda 1e-3 in most iterations) and ``[covariance]
    marginal covariances: indeterminate system ...; covariances omitted`` (information
    eigenvalues 8e-5 to 4e8). QR solves both: LM converges (graph error 290.80), ``ok``."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    data = gtsam.findExampleDataFile("Plaza2_DR.txt")
    (tmp_path / "run.yaml").write_text(
        f"log: {data}\nrobot: {{drive: increments}}\nestimator: smoother\n"
        "sensors: {ranges: {}}\noptions: {smoother: {slam: true, odometry_calibration: true}}\n"
    )
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), "MPLBACKEND": "Agg"}
    cmd = [sys.executable, "-m", "odofuse", "run", "run.yaml", "-o", "out"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["status"] == "ok", metrics["warnings"]
    assert metrics["extra"]["final_error"] < 300.0  # the cap stopped at 315.23
    traj = np.loadtxt(tmp_path / "out" / "trajectory.csv", delimiter=",", skiprows=1)
    P = np.stack([traj[:, [4, 5]], traj[:, [5, 7]]], axis=1)
    assert np.isfinite(traj).all() and np.linalg.eigvalsh(P)[:, 0].min() > 0
    marks = np.loadtxt(tmp_path / "out" / "landmarks.csv", delimiter=",", skiprows=1)
    assert len(marks) == 4 and np.isfinite(marks).all() and (marks[:, [3, 5]] > 0).all()


def test_optimistic_noise_model_is_reported():
    _, m = _run(sensors={"gps": {"sigma": 0.03}})  # the fixes are 0.3 m noisy
    assert m["status"] == "degraded"
    assert any(w.startswith("[residuals] gps") for w in m["warnings"]), m["warnings"]


def test_outlier_fraction_is_reported_even_under_a_robust_loss():
    def corrupt(log):
        gps = log.streams["gps"]
        rng = np.random.default_rng(3)
        vals = gps.values.copy()
        bad = rng.random(len(gps)) < 0.3
        vals[bad] += rng.normal(0.0, 10.0, (int(bad.sum()), 2))
        streams = {**log.streams, "gps": Stream("gps", gps.source, gps.t, gps.columns, vals)}
        return dataclasses.replace(log, streams=streams)

    res, m = _run(options={"robust": {"gps": "cauchy"}}, edit=corrupt)
    assert res.extra["residuals"]["gps"]["beyond_999"] > 0.2
    assert any(w.startswith("[outliers] gps") for w in m["warnings"]), m["warnings"]


def test_implausible_calibration_is_reported():
    # the wheel radii differ by 1 % but the prior claims 0.1 %
    scenario = {**SCENARIO, "systematic": {"E_d": 1.01, "E_b": 1.0}}
    res, m = _run(options={"odometry_calibration": [0.001, 0.001]}, scenario=scenario)
    assert abs(res.extra["calibration"]["wheel_radius_ratio"] - 1.0) > 5 * 0.001
    assert any(w.startswith("[calibration]") and "wheel_radius_ratio" in w for w in m["warnings"])


def test_keyframe_jumps_are_reported():
    # GPS that jumps 20 m sideways for the second half of the log; a Cauchy loss on the
    # wheels lets the one odometry factor at the jump go (the plaza2 failure in small)
    def teleport(log):
        gps = log.streams["gps"]
        vals = gps.values.copy()
        vals[gps.t > gps.t[-1] / 2, 1] += 20.0
        streams = {**log.streams, "gps": Stream("gps", gps.source, gps.t, gps.columns, vals)}
        return dataclasses.replace(log, streams=streams)

    # the GPS trusted (no loss; the plaza2 failure): the estimate follows it across the jump
    _, m = _run(edit=teleport, options={"robust": {"wheels": "cauchy", "gps": "none"}})
    assert m["status"] == "degraded"
    jumps = [f for f in m["findings"] if f["check"] == "jumps"]
    assert jumps and jumps[0]["sensor"] == "wheels" and jumps[0]["figure"] > 5.0
    # the default gate loss (Tukey) gives the readings on one side of the jump no influence
    # instead: the run is degraded by GPS outliers, not by keyframe jumps
    _, m = _run(edit=teleport, options={"robust": {"wheels": "cauchy"}})
    assert m["status"] == "degraded"
    assert any(w.startswith("[outliers] gps") for w in m["warnings"]), m["warnings"]
    assert not [f for f in m["findings"] if f["check"] == "jumps"]


def test_isam2_update_failure_is_a_finding(monkeypatch):
    calls = {"n": 0}
    real = gtsam.ISAM2.update

    class Failing(gtsam.ISAM2):
        def update(self, *a, **kw):
            calls["n"] += 1
            if calls["n"] == 20:
                raise RuntimeError("Indeterminate linear system detected (test)")
            return real(self, *a, **kw)

    monkeypatch.setattr(gtsam, "ISAM2", Failing)
    res, m = _run("isam2")
    assert m["status"] == "degraded"
    assert any("iSAM2 update failed at keyframe 19" in w for w in m["warnings"])
    assert np.isfinite(res.trajectory.poses).all() and res.trajectory.covariances is None


def test_a_slip_run_of_keyframe_intervals_longer_than_a_second_degrades():
    """The graph's form of the filters' ``slip_run``: two or more consecutive slipping
    keyframe intervals spanning more than ``SLIP_RUN_S``; one interval, or a shorter run, is
    the note alone."""
    from types import SimpleNamespace

    from odofuse.status.graph_checks import slip_findings

    problem = SimpleNamespace(
        kt=np.arange(0.0, 10.5, 0.5), models={"gyro": None}, gyro={"gyro": None}
    )
    scales = np.ones(20)
    scales[[3, 4]] = 5.0  # 1.5-2.5 s: 1 s, not more
    scales[[8]] = 9.0  # one interval
    assert [f.check for f in slip_findings(problem, scales)] == ["slip"]
    scales[[12, 13, 14]] = 7.0  # 6.0-7.5 s
    found = {f.check: f for f in slip_findings(problem, scales)}
    run = found["slip_run"]
    assert run.degrades and (run.t_start, run.t_end) == (6.0, 7.5) and not found["slip"].degrades


def test_the_lm_sends_a_damping_cholesky_refused_straight_to_qr(monkeypatch):
    """Once Cholesky has refused a damped system at some lambda, the Python LM sends every
    later system at that lambda or below to QR (issue 31: it retried Cholesky on each)."""
    from odofuse.estimators.graph import solvers

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    sigma = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), sigma))
    for i in range(3):
        graph.add(gtsam.BetweenFactorPose2(X(i), X(i + 1), gtsam.Pose2(1.0, 0.0, 0.5), sigma))
        values.insert(X(i), gtsam.Pose2(0.7 * i, 0.3 * i, 0.1 * i))
    values.insert(X(3), gtsam.Pose2(2.0, 1.0, 0.2))
    asked = []
    solve = solvers._solve_damped

    def refusing(damped, ordering, cholesky=True):  # Cholesky refuses at every lambda
        asked.append(cholesky)
        return solve(damped, ordering, cholesky=False)[0], cholesky

    monkeypatch.setattr(solvers, "_solve_damped", refusing)
    out = solvers.levenberg_marquardt(graph, values, {X(i): 3 for i in range(4)})
    assert out.reason == "converged" and out.iterations > 2 and out.error < 1e-12
    # lambda falls from its first value while the first steps are accepted: Cholesky is
    # asked once there; later, only where the damping rose above that (17 iterations, 46
    # systems: 15 asked)
    assert asked[:5] == [True, False, False, False, False]
    assert 1 < sum(asked) < len(asked) / 2
