"""The odofuse command: runs, exports, evaluation, plots, and one-line errors for bad input."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from odofuse import cli
from odofuse.cli import COMMANDS, main
from odofuse.options import to_mapping


def square_log(folder, n=200, dt=0.1):
    """An odometry.csv (increments) log driving a circle, with exact ground truth."""
    folder.mkdir(parents=True, exist_ok=True)
    t = (1.0 + dt * np.arange(n + 1)).tolist()
    ds, dth = 0.1, 0.05
    th = np.arange(n + 1) * dth
    # exact arc integration of constant (ds, dtheta) steps from the origin
    r = ds / dth
    x, y = (r * np.sin(th)).tolist(), (r * (1 - np.cos(th))).tolist()
    rows = "\n".join(f"{t[k + 1]!r},{ds},{dth}" for k in range(n))
    (folder / "odometry.csv").write_text("t,ds,dtheta\n" + rows + "\n")
    wrapped = ((th + math.pi) % (2 * math.pi) - math.pi).tolist()
    gt = "\n".join(f"{t[k]!r},{x[k]!r},{y[k]!r},{wrapped[k]!r}" for k in range(n + 1))
    (folder / "groundtruth.csv").write_text("t,x,y,theta\n" + gt + "\n")
    return folder


CONFIG = """\
log: {log}
robot:
  drive: increments
motion:
  integrator: exact
  k: [1.0e-4, 1.0e-4]
estimator: dead_reckoning
initial: {{pose: [0.0, 0.0, 0.0], sigma: [0.01, 0.01, 0.01]}}
output: {out}
"""


def make_run(tmp_path, log="log", out="out", text=None):
    square_log(tmp_path / "log")
    cfg = tmp_path / "run.yaml"
    cfg.write_text(text if text is not None else CONFIG.format(log=log, out=out))
    return cfg


def outputs_left(tmp_path):
    out = tmp_path / "out"
    return sorted(os.listdir(out)) if out.exists() else []


def test_run_config_writes_outputs(tmp_path, capsys):
    cfg = make_run(tmp_path)
    assert main(["run", str(cfg)]) == 0
    text = capsys.readouterr().out
    assert "dead_reckoning" in text and "position RMSE [m]" in text
    # <estimator>.tum and groundtruth.tum (the log has ground truth): issue 14
    assert outputs_left(tmp_path) == [
        "dead_reckoning.tum",
        "groundtruth.tum",
        "metrics.json",
        "trajectory.csv",
        "trajectory.png",
        "trajectory.tum",
    ]
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["estimator"] == "dead_reckoning" and m["poses"] == 201
    assert m["sensors"] == {"odometry": {"used": 200, "rejected": 0}}
    # exact integrator on exact arcs: dead reckoning reproduces the truth
    assert m["ate_rmse_m"] < 1e-9 and m["final_error_m"] < 1e-9
    assert m["repairs"] == {}


def test_run_override_out_and_estimator(tmp_path, capsys):
    cfg = make_run(tmp_path)
    rc = main(["run", str(cfg), "-o", str(tmp_path / "elsewhere"), "--estimator", "dead_reckoning"])
    assert rc == 0
    assert (tmp_path / "elsewhere" / "trajectory.tum").exists()


def test_repairs_reach_metrics(tmp_path, capsys):
    cfg = make_run(tmp_path)
    p = tmp_path / "log" / "odometry.csv"
    lines = p.read_text().splitlines()
    lines.insert(5, lines[4])  # exact duplicate row
    p.write_text("\n".join(lines) + "\n")
    assert main(["run", str(cfg)]) == 0
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["repairs"] == {"odometry.duplicate_rows": 1}
    assert m["ate_rmse_m"] < 1e-9


def test_encoder_rollover_run(tmp_path, capsys):
    # differential robot, 16-bit encoders that wrap while driving straight
    log = tmp_path / "wlog"
    log.mkdir()
    ticks = (65000 + 40 * np.arange(50)) % 65536
    rows = "\n".join(f"{0.1 * k!r},{int(v)},{int(v)}" for k, v in enumerate(ticks))
    (log / "wheels.csv").write_text("t,left,right\n" + rows + "\n")
    cfg = tmp_path / "w.yaml"
    cfg.write_text(
        "log: wlog\nrobot:\n  drive: differential\n  wheel_radius: 0.05\n  track_width: 0.3\n"
        "  encoder: {ticks_per_rev: 1000, rollover: 65536}\nestimator: dead_reckoning\n"
        "initial: {pose: [0, 0, 0]}\noutput: out\n"
    )
    assert main(["run", str(cfg)]) == 0
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["repairs"] == {"wheels.rollover_unwraps": 2}
    traj = np.loadtxt(tmp_path / "out" / "trajectory.csv", delimiter=",", skiprows=1)
    # 49 steps of 40 ticks = 1960 ticks = 1.96 rev of a 0.05 m wheel, straight ahead
    assert traj[-1, 1] == pytest.approx(1.96 * 2 * math.pi * 0.05, rel=1e-12)
    assert traj[-1, 2] == pytest.approx(0.0, abs=1e-12)


BAD_LOGS = [
    # (description, edit of odometry.csv line 4 (data row 3) or a file, expected fragments)
    (
        "nan",
        lambda d: replace_line(d / "odometry.csv", 3, "1.3,nan,0.05"),
        ["odometry.csv", "row 4", "'ds'", "not finite"],
    ),
    (
        "backwards",
        lambda d: replace_line(d / "odometry.csv", 3, "0.5,0.1,0.05"),
        ["odometry.csv", "row 4", "'t'", "backwards"],
    ),
    (
        "dup-conflict",
        lambda d: replace_line(d / "odometry.csv", 3, "1.2,0.2,0.05"),
        ["odometry.csv", "row 4", "'ds'", "duplicate"],
    ),
    (
        "missing-col",
        lambda d: (d / "odometry.csv").write_text("t,ds\n1.1,0.1\n"),
        ["odometry.csv", "row 1", "'dtheta'", "missing column"],
    ),
    (
        "empty",
        lambda d: (d / "odometry.csv").write_text("t,ds,dtheta\n"),
        ["odometry.csv", "row 2", "no data rows"],
    ),
    (
        "text",
        lambda d: replace_line(d / "odometry.csv", 3, "1.3,0.1,fast"),
        ["odometry.csv", "row 4", "'dtheta'", "not a number"],
    ),
    (
        "short-row",
        lambda d: replace_line(d / "odometry.csv", 3, "1.3,0.1"),
        ["odometry.csv", "row 4", "too few"],
    ),
    (
        "negative-range",
        lambda d: (d / "ranges.csv").write_text("t,id,range\n1.1,1,-2\n"),
        ["ranges.csv", "row 2", "'range'", "negative"],
    ),
    (
        "gt-angle",
        lambda d: replace_line(d / "groundtruth.csv", 2, "1.1,0,0,9.5"),
        ["groundtruth.csv", "row 3", "'theta'", "angle"],
    ),
]


def replace_line(path, lineno0, text):
    lines = path.read_text().splitlines()
    lines[lineno0] = text
    path.write_text("\n".join(lines) + "\n")


def assert_failed_cleanly(tmp_path, capsys, fragments):
    """One-line error naming every fragment, and no output file left behind."""
    err = capsys.readouterr().err.strip()
    assert err.startswith("odofuse: error: ") and "\n" not in err
    for frag in fragments:
        assert frag in err, (frag, err)
    assert outputs_left(tmp_path) == []


@pytest.mark.parametrize(("name", "edit", "fragments"), BAD_LOGS, ids=[b[0] for b in BAD_LOGS])
def test_bad_logs_fail_cleanly(tmp_path, capsys, name, edit, fragments):
    cfg = make_run(tmp_path)
    edit(tmp_path / "log")
    assert main(["run", str(cfg)]) == 2
    assert_failed_cleanly(tmp_path, capsys, fragments)


BAD_CONFIGS = [
    ("yaml", CONFIG.replace("drive: increments", "drive: [increments"), ["run.yaml", "line"]),
    ("unknown-key", CONFIG + "colour: red\n", ["run.yaml", "'colour'", "unknown key"]),
    (
        "type",
        CONFIG.replace("k: [1.0e-4, 1.0e-4]", "k: [1.0e-4, lots]"),
        ["run.yaml", "'motion.k[1]'", "number"],
    ),
    ("missing", CONFIG.replace("log: {log}\n", ""), ["run.yaml", "'log'", "missing"]),
    (
        "drive",
        CONFIG.replace("increments", "differential"),
        ["run.yaml", "'robot.wheel_radius'", "missing"],
    ),
    ("estimator", CONFIG.replace("dead_reckoning", "kalman9000"), ["'estimator'", "kalman9000"]),
    ("no-log", CONFIG.replace("log: {log}", "log: nowhere"), ["nowhere", "not found"]),
    (
        "wrong-stream",
        CONFIG.replace(
            "drive: increments", "drive: differential\n  wheel_radius: 0.1\n  track_width: 0.5"
        ),
        ["wheels.csv"],
    ),
]


@pytest.mark.parametrize(
    ("name", "text", "fragments"), BAD_CONFIGS, ids=[b[0] for b in BAD_CONFIGS]
)
def test_bad_configs_fail_cleanly(tmp_path, capsys, name, text, fragments):
    cfg = make_run(tmp_path, text=text.format(log="log", out="out"))
    assert main(["run", str(cfg)]) == 2
    assert_failed_cleanly(tmp_path, capsys, fragments)


def test_missing_config_file(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.yaml")]) == 2
    err = capsys.readouterr().err
    assert "nope.yaml" in err and "Traceback" not in err


def test_a_config_without_estimator_says_its_sensors_are_not_fused(tmp_path, capsys):
    # A config that lists a gyro but forgets `estimator:` runs dead reckoning (the default),
    # which fuses none of its sensors: the run says so under the table, through the CLI.
    square_log(tmp_path / "log")
    t = 1.0 + 0.1 * np.arange(1, 201)
    gyro = "\n".join(f"{v!r},0.5" for v in t.tolist())  # 0.05 rad per 0.1 s, as the wheels
    (tmp_path / "log" / "gyro.csv").write_text("t,wz\n" + gyro + "\n")
    text = CONFIG.format(log="log", out="out").replace("estimator: dead_reckoning\n", "")
    cfg = tmp_path / "run.yaml"
    cfg.write_text(text + "sensors: {gyro: {sigma: 0.01}}\n")
    cmd = [sys.executable, "-m", "odofuse", "run", str(cfg)]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    note = (
        "note: dead_reckoning fuses none of the configured sensors (gyro): `estimator: ekf` "
        "(or ukf, particle, smoother, isam2, fixed_lag) fuses them"
    )
    assert note in proc.stdout.splitlines(), proc.stdout
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["status"] == "ok"
    assert main(["run", str(cfg), "--estimator", "ekf", "-o", str(tmp_path / "ekf")]) == 0
    assert "fuses none" not in capsys.readouterr().out


def test_subprocess_error_has_no_traceback(tmp_path):
    cfg = make_run(tmp_path)
    replace_line(tmp_path / "log" / "odometry.csv", 3, "1.3,nan,0.05")
    proc = subprocess.run(
        [sys.executable, "-m", "odofuse", "run", str(cfg)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert "odometry.csv, row 4, column 'ds'" in proc.stderr
    help_text = subprocess.run(
        [sys.executable, "-m", "odofuse", "--help"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    ).stdout
    for name in ("run", "export", "eval", "plot"):
        assert name in help_text


def test_export_then_run_matches_builtin(tmp_path, capsys):
    assert main(["export", "builtin:plaza1", str(tmp_path / "plaza1")]) == 0
    out = capsys.readouterr().out
    assert "ranges.reordered = 425" in out and "initial pose" in out
    names = sorted(os.listdir(tmp_path / "plaza1"))
    assert names == ["groundtruth.csv", "map.csv", "odometry.csv", "ranges.csv"]
    base = cli.default_config("dead_reckoning")
    cfg = tmp_path / "p.yaml"
    pose = [0.0, 0.0, 4.222432]  # the dataset's published start (DRp row 0)
    cfg.write_text(
        f"log: plaza1\nrobot: {{drive: increments}}\n"
        f"motion: {json.dumps(to_mapping(base.motion))}\n"
        f"estimator: dead_reckoning\ninitial: {{pose: {pose}, sigma: "
        f"{list(base.initial.sigma)}}}\noutput: out\n"
    )
    assert main(["run", str(cfg)]) == 0
    assert main(["run", "--estimator", "dead_reckoning", "-o", str(tmp_path / "def")]) == 0
    a = json.loads((tmp_path / "out" / "metrics.json").read_text())
    b = json.loads((tmp_path / "def" / "dead_reckoning" / "metrics.json").read_text())
    assert a["ate_rmse_m"] == pytest.approx(b["ate_rmse_m"], rel=1e-9)
    assert 0.5 < b["ate_rmse_m"] < 10.0  # Plaza1 dead reckoning drifts by metres, not km


def test_default_run_reports_failed_estimator(tmp_path, capsys):
    rc = main(["run", "--estimator", "no_such_module_xyz:run", "-o", str(tmp_path / "o")])
    assert rc == 1
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("no_such_module_xyz"))
    assert "failed: ConfigError" in row and "no_such_module_xyz" in row
    assert not (tmp_path / "o" / "no_such_module_xyz:run").exists()


def test_eval_csv_and_tum(tmp_path, capsys):
    cfg = make_run(tmp_path)
    assert main(["run", str(cfg)]) == 0
    capsys.readouterr()
    gt = tmp_path / "log" / "groundtruth.csv"
    assert main(["eval", str(tmp_path / "out"), str(gt), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["ate_rmse_m"] < 1e-9 and res["poses"] == 201
    assert (
        main(
            [
                "eval",
                str(tmp_path / "out" / "trajectory.tum"),
                str(gt),
                "--align",
                "--delta",
                "2",
                "--unit",
                "s",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "ate_rmse_m" in text and "rpe_trans_m_per_2s" in text
    assert main(["eval", str(tmp_path / "missing.csv"), str(gt)]) == 2


def test_plot_command(tmp_path, capsys):
    cfg = make_run(tmp_path)
    assert main(["run", str(cfg)]) == 0
    os.remove(tmp_path / "out" / "trajectory.png")
    assert main(["plot", str(tmp_path / "out"), "--log", str(tmp_path / "log")]) == 0
    assert (tmp_path / "out" / "trajectory.png").read_bytes()[:4] == b"\x89PNG"


def test_commands_are_extensible(capsys):
    seen = {}

    def add(p):
        p.add_argument("--n", type=int, default=1)

    def handler(args):
        """Say hello."""
        seen["n"] = args.n
        return 0

    COMMANDS["hello"] = (add, handler)
    try:
        assert main(["hello", "--n", "3"]) == 0
        assert seen == {"n": 3}
    finally:
        del COMMANDS["hello"]
