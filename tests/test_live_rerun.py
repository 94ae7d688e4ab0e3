"""``odofuse run CONFIG --rerun`` (issue 27): the run as a Rerun recording beside the MCAP,
read back with rerun-sdk's own RRD reader."""

from __future__ import annotations

import dataclasses
import json
import re
import warnings

import pytest

pytest.importorskip("rosbags")
pytest.importorskip("rerun")

from rosbag_sim import CONFIG, simulate_robot, write_robot_bag  # noqa: E402

from odofuse.cli import main  # noqa: E402
from odofuse.outputs import read_trajectory_csv  # noqa: E402


def test_run_writes_a_rerun_recording(tmp_path):
    r = simulate_robot()
    n = 501
    short = dataclasses.replace(r, t=r.t[:n], truth=r.truth[:n], wheels=r.wheels[:n])
    bag = write_robot_bag(tmp_path / "bag", dataclasses.replace(short, gyro=r.gyro[:n]), "mcap")
    cfg = tmp_path / "run.yaml"
    cfg.write_text(CONFIG.format(bag=str(bag), estimator="ekf"))
    out = tmp_path / "out"
    assert main(["run", str(cfg), "-o", str(out), "--rerun"]) == 0
    rrd = out / "trajectory.rrd"
    assert rrd.exists() and (out / "trajectory.mcap").exists()
    assert not list(out.glob(".*.tmp"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from rerun.chunk import RrdReader

        summary = str(RrdReader(str(rrd)).store().summary())
    rows: dict[str, int] = {}
    for path, count in re.findall(r"^(\S+) rows=(\d+)", summary, flags=re.M):
        rows[path] = rows.get(path, 0) + int(count)
    traj = read_trajectory_csv(out / "trajectory.csv")
    metrics = json.loads((out / "metrics.json").read_text())
    assert rows["/world/trajectory"] == 1
    assert rows["/world/estimate"] == len(traj) == rows["/status/degraded"]
    assert rows["/world/covariance"] == len(traj)  # fewer than MAX_ELLIPSES poses: every one
    assert rows["/world/gps"] == 6  # the raw fixes, 1 Hz over 5 s
    timed = [f for f in metrics["findings"] if f.get("t_start") is not None]
    assert rows.get("/status/findings", 0) == len(timed)
