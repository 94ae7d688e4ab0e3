"""Output writers: formats, round trips, atomicity, and evo reading our TUM files."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from odofuse.io.atomic import atomic_write_text
from odofuse.outputs import (
    CSV_HEADER,
    read_trajectory_csv,
    read_tum,
    write_metrics,
    write_trajectory_csv,
    write_tum,
    yaw_to_quaternion,
)
from odofuse.rundir import write_outputs
from odofuse.trajectory import EstimateResult, Trajectory


def sample(n=50, seed=0, cov=True):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1 + 100.0
    th = np.cumsum(rng.normal(0, 0.1, n))
    xy = np.cumsum(np.column_stack([np.cos(th), np.sin(th)]) * 0.1, axis=0)
    poses = np.column_stack([xy, (th + math.pi) % (2 * math.pi) - math.pi])
    covs = None
    if cov:
        a = rng.normal(size=(n, 3, 3)) * 0.1
        covs = a @ np.swapaxes(a, 1, 2) + 1e-4 * np.eye(3)
    return Trajectory(t, poses, covs)


def test_csv_roundtrip_exact(tmp_path):
    traj = sample()
    p = write_trajectory_csv(tmp_path / "trajectory.csv", traj)
    assert p.read_text().splitlines()[0] == ",".join(CSV_HEADER)
    back = read_trajectory_csv(p)
    np.testing.assert_array_equal(back.t, traj.t)
    np.testing.assert_array_equal(back.poses, traj.poses)
    np.testing.assert_array_equal(back.covariances, traj.covariances)
    row = p.read_text().splitlines()[1].split(",")
    c = traj.covariances[0]
    assert [float(v) for v in row[4:]] == [c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2]]


def test_csv_without_covariance(tmp_path):
    p = write_trajectory_csv(tmp_path / "t.csv", sample(cov=False))
    assert "nan" in p.read_text().splitlines()[1]
    assert read_trajectory_csv(p).covariances is None


def test_tum_quaternion_and_roundtrip(tmp_path):
    np.testing.assert_allclose(
        yaw_to_quaternion([math.pi / 2]), [[0, 0, math.sqrt(0.5), math.sqrt(0.5)]]
    )
    traj = sample()
    p = write_tum(tmp_path / "trajectory.tum", traj)
    first = p.read_text().splitlines()[0].split()
    assert len(first) == 8 and float(first[3]) == 0.0
    back = read_tum(p)
    np.testing.assert_array_equal(back.t, traj.t)
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-12)


def test_metrics_json_is_strict(tmp_path):
    p = write_metrics(
        tmp_path / "m.json",
        {"a": np.float64(1.5), "b": math.nan, "c": np.int64(3), "d": {"e": [np.inf, 1]}},
    )
    assert json.loads(p.read_text()) == {"a": 1.5, "b": None, "c": 3, "d": {"e": [None, 1]}}
    assert "NaN" not in p.read_text()


def test_write_outputs_all_four(tmp_path):
    res = EstimateResult("ekf", sample(), used={"ranges": 3})
    paths = write_outputs(tmp_path / "out", res, {"estimator": "ekf", "poses": 50})
    # ekf.tum: the TUM file named after the estimator (issue 14), trajectory.tum its alias
    assert sorted(p.name for p in paths.values()) == [
        "ekf.tum",
        "metrics.json",
        "trajectory.csv",
        "trajectory.png",
        "trajectory.tum",
    ]
    assert sorted(os.listdir(tmp_path / "out")) == sorted(p.name for p in paths.values())


def test_failed_write_leaves_nothing(tmp_path):
    res = EstimateResult("ekf", sample())
    with pytest.raises(TypeError):
        write_outputs(tmp_path / "out", res, {"bad": object()})  # not JSON-serialisable
    assert os.listdir(tmp_path / "out") == []


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    p = atomic_write_text(tmp_path / "f.txt", "old")

    def failing(tmp):
        with open(tmp, "w") as fh:
            fh.write("half")
        raise RuntimeError("disk full")

    from odofuse.io.atomic import atomic_write

    with pytest.raises(RuntimeError):
        atomic_write(p, failing)
    assert p.read_text() == "old"
    assert os.listdir(tmp_path) == ["f.txt"]


def _evo_ape() -> str:
    """The evo_ape console script of this interpreter's environment (evo is a test extra)."""
    beside = Path(sys.executable).with_name("evo_ape")
    found = str(beside) if beside.exists() else shutil.which("evo_ape")
    assert found, "evo_ape not found: install the test extras (pip install -e '.[test]')"
    return found


def test_evo_reads_the_tum_file_of_odofuse_run(tmp_path):
    # A small odometry log with ground truth, run through the CLI; evo_ape reads the result.
    from odofuse.cli import main

    gt = sample(200, seed=1, cov=False)
    d = np.diff(gt.poses, axis=0)
    ds = np.hypot(d[:, 0], d[:, 1])
    log = tmp_path / "log"
    log.mkdir()
    rows = np.column_stack([gt.t[1:], ds, np.diff(np.unwrap(gt.poses[:, 2]))])
    np.savetxt(log / "odometry.csv", rows, delimiter=",", header="t,ds,dtheta", comments="")
    cfg = tmp_path / "run.yaml"
    x, y, th = (float(v) for v in gt.poses[0])
    cfg.write_text(
        f"log: log\nrobot: {{drive: increments}}\nestimator: dead_reckoning\n"
        f"initial: {{pose: [{x}, {y}, {th}]}}\noutput: out\n"
    )
    assert main(["run", str(cfg)]) == 0
    est = read_tum(tmp_path / "out" / "trajectory.tum")
    write_tum(tmp_path / "gt.tum", gt)
    proc = subprocess.run(
        [
            _evo_ape(),
            "tum",
            str(tmp_path / "gt.tum"),
            str(tmp_path / "out" / "trajectory.tum"),
            "--no_warnings",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    # evo's APE (translation part, no alignment) equals our ATE RMSE
    from odofuse.evaluation import ate

    rmse = float(
        next(
            line.split()[1] for line in proc.stdout.splitlines() if line.strip().startswith("rmse")
        )
    )
    assert rmse == pytest.approx(ate(est, gt).rmse_m, abs=5e-7)  # evo prints 6 decimals


def test_outputs_get_the_permissions_open_would_give(tmp_path):
    import os
    import stat

    from odofuse.io.atomic import atomic_write_text

    umask = os.umask(0o022)
    try:
        path = atomic_write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def test_block_writer_equals_per_row_format(tmp_path, monkeypatch):
    """Blocks, constant columns formatted once (-0.0 vs 0.0 kept apart): the same text as
    ``%.17g`` per value, row by row."""
    from odofuse import outputs
    from odofuse.se2 import wrap

    monkeypatch.setattr(outputs, "_ROWS", 7)
    rng = np.random.default_rng(3)
    n = 50
    poses = rng.normal(size=(n, 3)) * [1e3, 1e-3, 10]
    poses[10:30] = 0.0
    poses[12, 0] = -0.0
    cov = rng.normal(size=(n, 3, 3))
    cov = cov @ np.swapaxes(cov, 1, 2)
    cov[:20] = 0.0
    cov[5] = np.nan
    traj = Trajectory(np.cumsum(rng.random(n)), poses, cov)
    rows = np.column_stack(
        [traj.t, poses[:, :2], wrap(poses[:, 2])]
        + [cov[:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
    )
    want = (
        ",".join(CSV_HEADER) + "\n" + "".join(",".join(f"{v:.17g}" for v in r) + "\n" for r in rows)
    )
    assert outputs.trajectory_csv_text(traj) == want
    outputs.write_trajectory_csv(tmp_path / "t.csv", traj)
    assert (tmp_path / "t.csv").read_text() == want
    half = 0.5 * poses[:, 2]
    tum = np.column_stack([traj.t, poses[:, :2], np.zeros((n, 3)), np.sin(half), np.cos(half)])
    want_tum = "".join(" ".join(f"{v:.17g}" for v in r) + "\n" for r in tum)
    assert outputs.trajectory_tum_text(traj) == want_tum


def test_evo_t_max_diff_in_blocks_is_the_largest_nearest_stamp_distance(monkeypatch):
    """Blocks of 7 estimate times (unsorted ground truth, times outside its span): the largest
    distance to the nearest ground-truth stamp, as one whole-array pass computes it."""
    from odofuse import trajectory
    from odofuse.outputs import evo_t_max_diff

    monkeypatch.setattr(trajectory, "BLOCK", 7)
    rng = np.random.default_rng(5)
    t_gt = np.cumsum(rng.uniform(0.01, 0.2, 40))
    t_est = np.sort(rng.uniform(t_gt[0] - 1.0, t_gt[-1] + 1.0, 60))
    inside = t_est[(t_est >= t_gt[0]) & (t_est <= t_gt[-1])]
    want = max(float(np.abs(t_gt - s).min()) for s in inside)
    assert evo_t_max_diff(t_est, rng.permutation(t_gt)) == want
    assert evo_t_max_diff(t_gt, t_gt) == 0.0
    assert math.isnan(evo_t_max_diff(t_gt[:3] - 10.0, t_gt))
