"""Output writers: formats, round trips, atomicity, and evo reading our TUM files."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess

import numpy as np
import pytest

from odofuse.outputs import (
    CSV_HEADER,
    atomic_write_text,
    read_trajectory_csv,
    read_tum,
    write_metrics,
    write_outputs,
    write_trajectory_csv,
    write_tum,
    yaw_to_quaternion,
)
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
    assert sorted(p.name for p in paths.values()) == [
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

    from odofuse.outputs import atomic_write

    with pytest.raises(RuntimeError):
        atomic_write(p, failing)
    assert p.read_text() == "old"
    assert os.listdir(tmp_path) == ["f.txt"]


@pytest.mark.skipif(shutil.which("evo_ape") is None, reason="evo not installed")
def test_evo_reads_our_tum(tmp_path):
    gt = sample(200, seed=1, cov=False)
    rng = np.random.default_rng(2)
    est = Trajectory(gt.t, gt.poses + rng.normal(0, 0.01, gt.poses.shape))
    write_tum(tmp_path / "gt.tum", gt)
    write_tum(tmp_path / "est.tum", est)
    proc = subprocess.run(
        ["evo_ape", "tum", str(tmp_path / "gt.tum"), str(tmp_path / "est.tum"), "--no_warnings"],
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

    from odofuse.outputs import atomic_write_text

    umask = os.umask(0o022)
    try:
        path = atomic_write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
