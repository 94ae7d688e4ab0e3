"""The calibration drift check (``odofuse.status.drift``, issue 25): a Kalman filter's
calibration estimate is a martingale, so its change between snapshots has the variance its
updates and random walk explain; the check fires when it moved more.

The rate is checked on a scalar Kalman filter of a constant (seeded), the detection on a step
of that constant, the replay and memory bounds on the class itself, and the user's path
through ``odofuse run`` on a simulated CSV folder whose gyro bias steps mid-run.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import binom

from odofuse.status.drift import MAX_LAG, Drift

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_status as bs  # noqa: E402


def _scalar_run(seed: int, step: float = 0.0, n: int = 400, alpha: float = 0.05) -> Drift:
    """A Kalman filter of one constant (random walk ``q`` per s) read every 0.1 s with noise
    0.1, from a prior sigma 1; the truth steps by ``step`` at 20 s. Snapshots every 1 s."""
    rng = np.random.default_rng(seed)
    q, r, dt = 1e-6, 0.1**2, 0.1
    truth, x, P = rng.normal(0.0, 1.0), 0.0, 1.0
    d = Drift(["c"], [0], np.array([q]), {"c": "sensor"}, alpha, 1.0)
    for k in range(1, n + 1):
        t = k * dt
        truth += rng.normal(0.0, np.sqrt(q * dt)) + (step if k == 200 else 0.0)
        P += q * dt
        z = truth + rng.normal(0.0, np.sqrt(r))
        g = P / (P + r)
        x, P = x + g * (z - x), (1.0 - g) * P
        if t >= d.next_t - 1e-12:
            d.observe(t, np.array([x]), np.array([P]))
    return d


def test_a_consistent_filter_exceeds_its_bound_at_most_at_the_stated_rate():
    # alpha 0.05 per run, 200 seeds: more than the binomial 99 % bound would refute the rate
    over = sum(_scalar_run(seed).ratio() > 1.0 for seed in range(200))
    assert over <= binom.ppf(0.99, 200, 0.05), over


def test_a_step_of_the_constant_is_found_with_its_times():
    d = _scalar_run(7, step=0.2, alpha=1e-3)
    (f,) = d.findings()
    assert f.check == "calibration_drift" and f.degrades and f.sensor == "sensor"
    # the filter follows the step slowly (its gain is small by then): the span is after it
    assert f.figure > 1.0 and 20.0 < f.t_end
    assert "c moved" in f.line() and "[calibration_drift]" in f.line()
    assert not _scalar_run(7, alpha=1e-3).findings()  # the same log without the step


def test_a_replay_truncates_and_retakes_the_same_snapshots():
    a = _scalar_run(3, step=0.2)
    ts = [0.1 + k for k in range(len(a))]
    rows = [(a._t[k], a._v[k].copy(), a._var[k].copy()) for k in range(len(a))]
    assert np.allclose([r[0] for r in rows], ts)
    b = Drift(["c"], [0], np.array([1e-6]), {}, 0.05, 1.0)
    for t, v, var in rows:
        b.observe(t, v, var)
    n = len(b) // 2
    ratio_then = b._worst[n - 1][0]
    b.truncate(n)
    assert len(b) == n and b.ratio() == ratio_then and b.next_t == rows[n - 1][0] + 1.0
    for t, v, var in rows[n:]:
        b.observe(t, v, var)
    assert len(b) == len(a) and b.ratio() == a.ratio()


def test_memory_is_allocated_once_and_a_finding_outlives_the_snapshots_it_came_from():
    d = Drift(["c"], [0], np.array([0.0]), {}, 1e-3, 1.0)
    held = d._v.nbytes + d._var.nbytes + d._t.nbytes + d._worst.nbytes
    for k in range(5 * MAX_LAG):
        x = 5.0 if k == 10 else 0.0  # one jump the variance cannot explain
        d.observe(float(k), np.array([x]), np.array([1.0 / (k + 1)]))
    assert len(d) == 5 * MAX_LAG
    assert d._v.nbytes + d._var.nbytes + d._t.nbytes + d._worst.nbytes == held
    (f,) = d.findings()
    assert f.t_start <= 10.0 <= f.t_end <= 11.0
    with pytest.raises(ValueError, match="no longer held"):
        d.truncate(len(d) - MAX_LAG)  # further back than a late window reaches


def _bias_step_log(folder: Path, seed: int, at: float = 45.0) -> Path:
    """A differential robot with gyro and 1 Hz GPS (``bench_status``'s scenario and the config
    a user would write), written as a CSV folder; then the gyro's rates gain 0.03 rad/s from
    ``at`` s on, as a bias step does (``bench_status.inject``'s ``gyro_bias_step``, and its
    ``gyro_bias_step_60s`` at 60 s)."""

    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import write_log
    from odofuse.teaching.simulate import simulate

    noise = bs.NOISE[seed % len(bs.NOISE)]
    sc = bs.scenario_dict(seed, "differential", "gyro_gps", noise, "gyro_bias_step")
    write_log(simulate(scenario_from_dict(sc, f"seed {seed}")), folder)
    gyro = folder / "gyro.csv"
    lines = gyro.read_text().splitlines()
    cols = lines[0].split(",")
    it, iw = cols.index("t"), cols.index("wz")
    out = [lines[0]]
    for line in lines[1:]:
        v = line.split(",")
        if float(v[it]) >= at:
            v[iw] = repr(float(v[iw]) + 0.03)
        out.append(",".join(v))
    gyro.write_text("\n".join(out) + "\n")
    cfg = folder / "config.yaml"
    cfg.write_text(yaml.safe_dump(bs.user_config(sc, noise), sort_keys=False))
    return cfg


@pytest.mark.parametrize(
    "estimator",
    ["ekf", "ukf"],  # 2.7 s each since robust odometry runs in the kernels (filterpy: 13 s)
)
def test_odofuse_run_says_degraded_by_the_drift_check_on_a_gyro_bias_step(tmp_path, estimator):
    # seed 1015 of bench_status's gyro bias step: the innovations stay in their bands (every
    # other check says ok), the calibration absorbed the step (docs/trust.md)
    cfg = _bias_step_log(tmp_path / "log", 1015)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "odofuse", "run", str(cfg), "--estimator", estimator]
    cmd += ["-o", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    m = json.loads((out / "metrics.json").read_text())
    m = m.get(estimator, m)
    assert m["status"] == "degraded"
    drift = [w for w in m["warnings"] if w.startswith("[calibration_drift]")]
    assert drift, m["warnings"]
    assert m["extra"]["calibration_drift"]["ratio"] > 1.0


@pytest.mark.parametrize("estimator", ["ekf", "dead_reckoning"])
def test_odofuse_run_says_degraded_by_the_gyros_scan_on_a_bias_step_inside_a_turn(
    tmp_path, estimator
):
    # seed 9809 of bench_status's gyro_bias_step_60s (GPS 2 m): the filter's heading follows
    # the gyro, its bias held, and every check of the absolute sensor stays in band (NEES 71
    # at ok before the gyro was scanned); the gyro's innovations against the wheels keep a
    # mean of 0.2-0.3 of their sigma from 60 s on, which its blocks of 1 s see (docs/trust.md,
    # "The gyro in the innovation-mean scan"). Dead reckoning carries the companion EKF's.
    cfg = _bias_step_log(tmp_path / "log", 9809, at=60.0)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "odofuse", "run", str(cfg), "--estimator", estimator]
    proc = subprocess.run(cmd + ["-o", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    m = json.loads((out / "metrics.json").read_text())
    m = m.get(estimator, m)
    assert m["status"] == "degraded"
    scan = [w for w in m["warnings"] if w.startswith("[innovation_mean] gyro")]
    assert scan and "blocks of >= 1 s" in scan[0], m["warnings"]
    start = float(scan[0].split(", ")[1].split("-")[0])  # "[...] gyro, 52.16-88.56 s: ..."
    assert 40.0 <= start  # its first window ends after the step
    if estimator == "ekf":
        assert m["sensors"]["gyro"]["mde"]["innovation_mean"] < 0.03  # rad/s: the step


def _stream(loc, log, cfg, t, U, drift=None):
    """Feed ``log`` to the live ``loc`` in time order (odometry ``t``, ``U``), asking for its
    health after every odometry step (with ``drift``, only after the steps at which that
    :class:`Drift` took a snapshot): ``(statuses, final health)``."""
    from odofuse.estimators.assembly import events

    now, seen = [], 0
    for te, kind, stream, i in events(log, t, U, [s for s in cfg.sensors if s in log.streams]):
        if kind == 1:
            loc.add_odometry(te, U[i])
            if drift is not None and len(drift) == seen:
                continue
            seen = len(drift) if drift is not None else 0
            now.append(loc.health().status)
        else:
            loc.add_measurement(stream, log.streams[stream].row(i))
    loc.finish()
    return now, loc.health()


@pytest.mark.parametrize(
    "estimator",
    ["ekf", pytest.param("ukf", marks=pytest.mark.slow)],  # the live UKF: 12 s
)
def test_the_live_localizer_finds_the_same_drift_as_the_offline_run(estimator):

    from odofuse.estimators import ekf, run_estimator, ukf
    from odofuse.estimators.common import odometry_inputs
    from odofuse.estimators.localizer import assemble
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.motion import motion_model_from_config
    from odofuse.status.findings import assess, status_of

    log, cfg, _ = bs.make_case(1015, "gyro_bias_step")
    cfg, log = apply_log_defaults(cfg, log)
    cfg = dataclasses.replace(cfg, estimator=estimator)
    offline = run_estimator(estimator, log, cfg)
    (want,) = [f for f in offline.findings if f.check == "calibration_drift"]
    t, U = odometry_inputs(log, motion_model_from_config(cfg))
    make = {"ekf": ekf, "ukf": ukf}[estimator].make_backend
    loc = assemble(cfg, estimator, make, float(t[0]), log, keep_trajectory=False)
    now, h = _stream(loc, log, cfg, t, U)
    (got,) = [f for f in h.findings if f.check == "calibration_drift"]
    assert (got.t_start, got.t_end, got.message) == (want.t_start, want.t_end, want.message)
    assert h.run_status == status_of(assess(offline)) == "degraded"
    assert "degraded" in now  # at the snapshot that found it


def test_a_live_particle_filter_carries_an_ekfs_drift_as_its_offline_run_does():
    # Offline a particle run carries the drift check of an EKF of its log and config
    # (odofuse.status.cross_check.COMPANION); live (Localizer.from_config) the same EKF runs
    # beside it on the same readings (seed 1015's gyro bias step).
    from odofuse.estimators.common import odometry_inputs
    from odofuse.estimators.localizer import Localizer
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.motion import motion_model_from_config
    from odofuse.status.cross_check import companion_findings

    log, cfg, _ = bs.make_case(1015, "gyro_bias_step")
    cfg, log = apply_log_defaults(cfg, log)
    cfg = dataclasses.replace(cfg, estimator="particle")
    carried = companion_findings(cfg, log)  # what the offline run carries
    (want,) = [f for f in carried if f.check == "calibration_drift"]
    t, U = odometry_inputs(log, motion_model_from_config(cfg))
    loc = Localizer.from_config(
        cfg, float(t[0]), landmarks=log.landmarks, initial_pose=log.initial_pose
    )
    assert loc.companion is not None and loc.companion.name == "ekf"
    now, h = _stream(loc, log, cfg, t, U, drift=loc.companion.monitor.drift)
    (got,) = [f for f in h.findings if f.check == "calibration_drift"]
    assert got == want and got.message.startswith("seen by an EKF of this log and config: ")
    # the EKF's innovation-mean scans are carried alike (drift.seen_by_ekf)
    assert set(carried) <= set(h.findings)
    assert h.run_status == "degraded" and "degraded" in now
    # with the second opinion off, neither the offline run nor the live one has a companion
    off = dataclasses.replace(cfg, options={**cfg.options, "cross_check": {"smoother": "off"}})
    assert Localizer.from_config(off, 0.0, landmarks=log.landmarks).companion is None


def test_odofuse_run_of_the_smoother_carries_an_ekfs_drift_finding(tmp_path):
    # The batch smoother's calibration is not a martingale (it relinearises), so it has no
    # drift check of its own; offline it carries an EKF's of the same log and config
    # (odofuse.status.cross_check.COMPANION). Seed 1015: every check of the smoother says ok.
    cfg = _bias_step_log(tmp_path / "log", 1015)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "odofuse", "run", str(cfg), "--estimator", "smoother"]
    proc = subprocess.run(cmd + ["-o", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    m = json.loads((out / "metrics.json").read_text())
    assert m["status"] == "degraded"
    (drift,) = [w for w in m["warnings"] if w.startswith("[calibration_drift]")]
    assert "seen by an EKF of this log and config: wheel_radius_scale moved" in drift
    assert m["alpha"]["checks"]["calibration_drift"] == 1e-3  # counted in the run's budget
    assert m["alpha"]["total"] <= m["alpha"]["alpha_run"]


def test_every_companion_estimator_carries_the_same_finding_from_one_shared_ekf(monkeypatch):
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.rundir import checked_metrics, estimate, smoother_reference
    from odofuse.status import cross_check

    log, cfg, _ = bs.make_case(1015, "gyro_bias_step")
    cfg, log = apply_log_defaults(cfg, log)
    runs = []
    real = cross_check.companion_findings

    def counted(config, log):
        runs.append(config.estimator)
        return real(config, log)

    monkeypatch.setattr("odofuse.status.cross_check.companion_findings", counted)
    ekf = estimate(dataclasses.replace(cfg, estimator="ekf"), log)[0]
    (want,) = [f.message for f in ekf.findings if f.check == "calibration_drift"]
    (scan,) = [f.message for f in ekf.findings if f.check == "innovation_mean"]  # its GPS
    ref = smoother_reference(cfg, log)
    for est in sorted(cross_check.COMPANION):
        run_cfg = dataclasses.replace(cfg, estimator=est)
        result, runtime = estimate(run_cfg, log, ref)
        m = checked_metrics(run_cfg, log, result, runtime, ref)
        found = [f for f in m["findings"] if f["check"] == "calibration_drift"]
        assert [f["message"] for f in found] == [f"seen by an EKF of this log and config: {want}"]
        assert m["status"] == "degraded" and m["alpha"]["checks"]["calibration_drift"] == 1e-3
        # the EKF's innovation-mean scan too, dead reckoning included (session 44), budgeted
        found = [f for f in m["findings"] if f["message"].startswith("seen by an EKF")]
        assert [f["message"] for f in found if f["check"] == "innovation_mean"] == [
            f"seen by an EKF of this log and config: {scan}"
        ]
        assert m["alpha"]["checks"]["companion_innovation_mean:gps"] == 1e-3
        if est == "dead_reckoning":  # its own check is still counted beside the companion
            assert m["alpha"]["checks"]["gyro_wheels"] == 1e-3
    assert len(runs) == 1  # one EKF for the five runs of the log (the shared reference's)
    # out of the second opinion's scope (switched off) there is no companion and no budget
    off = dataclasses.replace(cfg, estimator="smoother")
    off = dataclasses.replace(off, options={**off.options, "cross_check": {"smoother": "off"}})
    result, runtime = estimate(off, log)
    m = checked_metrics(off, log, result, runtime)
    assert "calibration_drift" not in m["alpha"]["checks"]
    assert not [f for f in m["findings"] if f["check"] == "calibration_drift"]


def test_an_ekf_that_cannot_run_the_log_leaves_a_note_not_a_crash(monkeypatch):
    import odofuse.estimators
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.rundir import checked_metrics, estimate

    log, cfg, _ = bs.make_case(1003, None)
    cfg, log = apply_log_defaults(cfg, log)
    cfg = dataclasses.replace(cfg, estimator="smoother")
    result, runtime = estimate(cfg, log)
    real = odofuse.estimators.run_estimator

    def no_ekf(name, *args, **kw):
        if name == "ekf":
            raise ValueError("no EKF here")
        return real(name, *args, **kw)

    monkeypatch.setattr(odofuse.estimators, "run_estimator", no_ekf)
    m = checked_metrics(cfg, log, result, runtime)
    (note,) = [f for f in m["findings"] if f["check"] == "calibration_drift"]
    assert not note["degrades"] and m["status"] == "ok"
    assert note["message"].endswith(
        "could not test the calibration's drift: ValueError: no EKF here"
    )


def test_an_ekf_degraded_by_its_own_checks_cannot_judge_the_drift(monkeypatch):
    # Plaza1's .mat with the minimal config: the EKF recovers and rejects ranges, and its
    # calibration moves with its own failure, not the log's; that is a note, not a finding.
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.status import cross_check
    from odofuse.status.findings import Finding

    log, cfg, _ = bs.make_case(1015, "gyro_bias_step")
    cfg, log = apply_log_defaults(cfg, log)
    found = cross_check.companion_findings(cfg, log)
    assert "calibration_drift" in {f.check for f in found}
    assert all(f.degrades and f.message.startswith("seen by an EKF") for f in found)
    also = Finding("recovery", "re-opened 2 time(s)", sensor="ranges")
    monkeypatch.setattr(cross_check, "assess", lambda result: [*result.findings, also])
    (note,) = cross_check.companion_findings(cfg, log)
    assert not note.degrades
    assert note.message.endswith(
        "it is degraded by recovery itself, so its calibration's path is no evidence about the log"
    )
    # Its NIS tests are not its own failure: like the scan they test its innovations against
    # the config's model, which the other estimator shares (fresh seed 9415's bias step: the
    # smoother was ok at NEES 99 while the EKF said nis_run, the scan and the drift)
    nis = [
        Finding("nis", "mean NIS above its band", sensor="gps"),
        Finding("nis_run", "mean NIS of the run above its band", sensor="gps"),
    ]
    monkeypatch.setattr(cross_check, "assess", lambda result: [*result.findings, *nis])
    assert cross_check.companion_findings(cfg, log) == found
