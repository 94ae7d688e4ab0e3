"""``odofuse batch``: identical to ``odofuse run``, failure rows, resume, a real scheduler and
workers, a worker killed mid-batch, and ``--split`` against the unsplit smoother."""

from __future__ import annotations

import importlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from odofuse.batch import log_names, run_batch
from odofuse.cli import main

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

BEACONS = np.array([[1, 0.0, 8.0], [2, 0.0, -8.0], [3, 12.0, 0.0], [4, -12.0, 0.0]])
LAP_S = 2 * 2 * np.pi * 5.0 / 0.5  # figure eight of radius 5 m at 0.5 m/s


@pytest.fixture(scope="module")
def sim():
    """The simulator module (the one place to change when it moves to odofuse.teaching)."""
    return importlib.import_module("odofuse.teaching.simulate")


def make_log(sim, folder: Path, laps: int, seed: int, estimator: str) -> Path:
    """A figure-eight log with GPS and beacon ranges (dt 1/16 s: exact float time stamps)."""
    sc = sim.Scenario(
        path={"kind": "figure_eight", "radius": 5.0, "speed": 0.5, "laps": laps},
        dt=0.0625,
        wheel_noise=sim.WheelNoise(k=1e-6),
        gps=sim.GpsSpec(sigma=1.0, rate=1.0),
        ranges=sim.RangeSpec(sigma=0.1, rate=1.0, max_range=30.0),
        beacons=BEACONS,
        encoder=sim.EncoderSpec(4096.0, 65536),
        seed=seed,
    )
    sim.write_log(sim.simulate(sc), folder, estimator=estimator)
    return folder


@pytest.fixture(scope="module")
def logs(sim, tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    # two logs share the base name "log" to exercise the unique output names
    paths = [
        make_log(sim, root / f"robot{i}" / "log", 1, seed=i, estimator="smoother") for i in (1, 2)
    ]
    paths.append(make_log(sim, root / "short", 1, seed=3, estimator="smoother"))
    bad = root / "bad"
    bad.mkdir()
    (bad / "wheels.csv").write_text("t,left,right\n0,0,0\nabc,1,1\n", encoding="utf-8")
    return {"good": paths, "bad": bad, "config": paths[0] / "config.yaml"}


@pytest.fixture(scope="module")
def client():
    from odofuse.batch import local_client

    c = local_client(2)
    yield c
    cluster = c.cluster
    c.close()
    cluster.close()


def _metrics(folder: Path) -> dict:
    """metrics.json without its wall-clock times and the config file's path."""
    m = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    m.get("extra", {}).pop("solve_s", None)
    return {k: v for k, v in m.items() if k not in ("runtime_s", "config")}


def test_unique_names():
    names = log_names(["/a/r1/log", "/a/r2/log", "/b/x.db3", "/c/x", "builtin:plaza1"])
    assert names == ["r1-log", "r2-log", "b-x", "c-x", "plaza1"]
    assert log_names(["/a/r/log", "/b/r/log", "/c/other"]) == ["r-log", "r-log-2", "other"]


def test_batch_equals_run_to_the_last_digit(logs, client, tmp_path):
    out = tmp_path / "batch"
    summary = run_batch(logs["config"], logs["good"], out, client)
    assert [r["status"] for r in summary] == ["ok"] * 3
    assert [r["name"] for r in summary] == ["robot1-log", "robot2-log", "short"]
    cfg = yaml.safe_load(logs["config"].read_text(encoding="utf-8"))
    for rec in summary:
        cfg["log"] = rec["log"]
        one = tmp_path / f"{rec['name']}.yaml"
        one.write_text(yaml.safe_dump(cfg), encoding="utf-8")
        assert main(["run", str(one), "-o", str(tmp_path / "run" / rec["name"])]) == 0
        a, b = out / rec["name"], tmp_path / "run" / rec["name"]
        for f in ("trajectory.csv", "trajectory.tum"):
            assert (a / f).read_bytes() == (b / f).read_bytes()
        assert _metrics(a) == _metrics(b)
        assert rec["poses"] == _metrics(b)["poses"]
        assert rec["ate_rmse_m"] == _metrics(b)["ate_rmse_m"]
    rows = (out / "summary.csv").read_text(encoding="utf-8").splitlines()
    assert rows[0].split(",")[:4] == ["log", "name", "status", "warnings"] and len(rows) == 4
    assert len(json.loads((out / "summary.json").read_text(encoding="utf-8"))) == 3
    assert (out / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert summary.to_pandas().shape == (3, 10)


def test_bad_log_is_one_failed_row(logs, client, tmp_path, capsys):
    out = tmp_path / "out"
    specs = [logs["good"][2], logs["bad"], tmp_path / "missing"]
    code = main(["batch", str(logs["config"]), *map(str, specs), "-o", str(out), "--workers", "1"])
    assert code == 1
    rows = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert [r["status"] for r in rows] == ["ok", "failed", "failed"]
    assert "wheels.csv" in rows[1]["error"] and "\n" not in rows[1]["error"]
    assert "not found" in rows[2]["error"]
    assert is_dir_only(out, ["short", "summary.csv", "summary.json", "summary.png"])
    text = capsys.readouterr().out
    assert "bad: " in text and "Traceback" not in text
    assert main(["batch", str(logs["config"]), str(tmp_path / "*.nothing"), "-o", str(out)]) == 2


def is_dir_only(folder: Path, names) -> bool:
    """``folder`` holds exactly ``names`` (no temporary or half-written folder)."""
    return sorted(p.name for p in folder.iterdir()) == sorted(names)


def test_resume_skips_and_force_redoes(logs, client, tmp_path):
    out = tmp_path / "out"
    log = logs["good"][2]
    first = run_batch(logs["config"], [log], out, client)
    stamp = (out / "short" / "trajectory.csv").stat().st_mtime_ns
    (out / ".short.tmp-deadbeef").mkdir()  # what a killed batch leaves behind
    (out / ".short.tmp-deadbeef" / "trajectory.csv").write_text("half", encoding="utf-8")
    again = run_batch(logs["config"], [log], out, client)
    assert again[0]["resumed"] and not first[0]["resumed"]
    assert again[0]["ate_rmse_m"] == first[0]["ate_rmse_m"]
    assert (out / "short" / "trajectory.csv").stat().st_mtime_ns == stamp
    assert not (out / ".short.tmp-deadbeef").exists()
    forced = run_batch(logs["config"], [log], out, client, force=True)
    assert not forced[0]["resumed"]
    assert (out / "short" / "trajectory.csv").stat().st_mtime_ns != stamp
    assert is_dir_only(out, ["short", "summary.csv", "summary.json", "summary.png"])


# ------------------------------------------------------------- a real scheduler and workers
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaskProcesses:
    """A ``dask scheduler`` and ``dask worker`` subprocesses on 127.0.0.1, torn down by pid."""

    def __init__(self, workers: int, tmp: Path):
        self.port = _free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.procs: list[subprocess.Popen] = []
        self.tmp = tmp
        self._start("scheduler", "--host", "127.0.0.1", "--port", str(self.port))
        self._wait(lambda c: True)
        for _ in range(workers):
            # no nanny: the worker process is the one a test kills
            self._start("worker", self.address, "--nthreads", "1", "--no-nanny")
        self._wait(lambda c: len(c.scheduler_info(n_workers=-1)["workers"]) >= workers)

    def _start(self, *args: str) -> None:
        log = open(self.tmp / f"dask-{len(self.procs)}.log", "w")  # noqa: SIM115
        cmd = [sys.executable, "-m", "dask", *args, "--no-dashboard"]
        self.procs.append(
            subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        )
        log.close()

    def _wait(self, ready, timeout: float = 60.0) -> None:
        from distributed import Client

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                with Client(self.address, timeout="2s") as c:
                    if ready(c):
                        return
            except OSError:
                pass
            time.sleep(0.3)
        self.close()
        raise RuntimeError(f"dask processes not ready: see {self.tmp}/dask-*.log")

    def close(self) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in self.procs:
            try:
                # a worker without nanny sometimes outlives SIGTERM by more than 10 s (1 run
                # in 3 here; 10-20 s of the not-slow tier's teardown): killed after 2 s
                p.wait(timeout=2)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)


@pytest.fixture(scope="module")
def dask_processes(tmp_path_factory):
    """Shared by the two tests below; the second one kills a worker, so it runs last."""
    procs = DaskProcesses(2, tmp_path_factory.mktemp("dask"))
    yield procs
    procs.close()


def test_batch_through_a_scheduler_and_two_workers(logs, dask_processes, tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "odofuse", "batch", str(logs["config"]), *map(str, logs["good"])]
    cmd += ["-o", str(out), "--scheduler", dask_processes.address]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert [r["status"] for r in rows] == ["ok"] * 3
    assert "3 logs" in done.stdout


@pytest.mark.slow  # a Dask worker is killed and replaced mid-batch: 6 s alone, 17 s in the suite
def test_worker_killed_mid_batch_every_log_completes(sim, logs, dask_processes, tmp_path):
    from distributed import Client

    specs = [
        make_log(sim, tmp_path / f"k{i}", 2, seed=10 + i, estimator="smoother") for i in range(6)
    ]
    out = tmp_path / "out"
    with Client(dask_processes.address) as client:
        pids = client.run(os.getpid)
        result: dict = {}
        thread = threading.Thread(
            target=lambda: result.setdefault(
                "s", run_batch(specs[0] / "config.yaml", specs, out, client)
            )
        )
        thread.start()
        victim = None
        deadline = time.monotonic() + 120
        while victim is None and time.monotonic() < deadline:
            busy = [w for w, keys in client.processing().items() if keys]
            done = [p for p in out.glob("k*") if p.is_dir()] if out.exists() else []
            if busy and done:  # one log finished, another is running: kill its worker
                victim = busy[0]
            time.sleep(0.05)
        assert victim is not None, "no worker was busy"
        os.kill(pids[victim], signal.SIGKILL)
        thread.join(timeout=240)
    summary = result["s"]
    assert [r["status"] for r in summary] == ["ok"] * 6
    assert all((out / f"k{i}" / "metrics.json").exists() for i in range(6))
    assert is_dir_only(
        out, [f"k{i}" for i in range(6)] + ["summary.csv", "summary.json", "summary.png"]
    )


# --------------------------------------------------------------------------------- --split
def test_split_matches_the_unsplit_smoother_away_from_the_seams(sim, client, tmp_path):
    from odofuse.config import load_config
    from odofuse.estimators import run_estimator
    from odofuse.io.loader import load_log_for
    from odofuse.outputs import read_trajectory_csv
    from odofuse.trajectory import interpolate_poses

    folder = make_log(sim, tmp_path / "long", 5, seed=21, estimator="smoother")  # ~630 s
    cfg = load_config(folder / "config.yaml")
    whole = run_estimator("smoother", load_log_for(cfg), cfg).trajectory
    summary = run_batch(cfg, [folder], tmp_path / "out", client, split=200.0)
    assert summary[0]["status"] == "ok", summary[0]["error"]
    meta = json.loads((tmp_path / "out" / "long" / "metrics.json").read_text(encoding="utf-8"))
    split = meta["extra"]["split"]
    assert len(split["windows"]) == 4 and split["anchored"]
    overlap = split["windows"][1]["core_start"] - split["windows"][1]["start"]
    assert overlap == 20.0  # 10 % of the window, whole seconds
    stitched = read_trajectory_csv(tmp_path / "out" / "long" / "trajectory.csv")
    assert np.all(np.diff(stitched.t) > 0) and stitched.t[0] == whole.t[0]
    d = interpolate_poses(whole, stitched.t) - stitched.poses
    err = np.hypot(d[:, 0], d[:, 1])
    seams = np.array([s["t"] for s in split["seams"]])
    away = np.all(np.abs(stitched.t[:, None] - seams[None, :]) > overlap, axis=1)
    assert away.sum() > 0.5 * len(err)
    assert err[away].max() < 0.01
    # no jump at a seam: steps there are no larger than the path's ordinary steps
    steps = np.hypot(*np.diff(stitched.poses[:, :2], axis=0).T)
    near = np.any(np.abs(stitched.t[1:, None] - seams[None, :]) <= overlap, axis=1)
    assert steps[near].max() <= 1.5 * steps[~near].max()
    for s in split["seams"]:
        assert s["max_position_diff_m"] < 0.5


def test_a_rerun_over_fewer_logs_lists_the_stale_folders(logs, client, tmp_path, capsys):
    """Issue 30: a re-run batch rewrote summary.csv but left the folders of logs no longer
    given, silently. They are listed (never deleted: they may be a run's only copy)."""
    from odofuse.batch import print_summary

    out = tmp_path / "out"
    first = run_batch(logs["config"], logs["good"][1:], out, client)
    assert [r["name"] for r in first] == ["log", "short"] and not first.stale
    again = run_batch(logs["config"], logs["good"][2:], out, client)
    assert [r["name"] for r in again] == ["short"] and again[0]["resumed"]
    assert again.stale == ["log"]
    print_summary(again, out)
    text = capsys.readouterr().out
    assert f"note: 1 output folder(s) in {out}/ belong to no log of this batch" in text
    assert text.rstrip().endswith(": log")
    assert (out / "log" / "metrics.json").exists()
    rows = (out / "summary.csv").read_text(encoding="utf-8").splitlines()
    assert len(rows) == 2 and ",short," in rows[1]


def test_a_dead_reckoning_batch_says_its_sensors_are_not_fused(logs, client, tmp_path, capsys):
    """A fleet config that forgot `estimator:` runs dead reckoning on every log, which fuses
    none of the configured sensors: the summary says so (as `odofuse run` does)."""
    from odofuse.batch import print_summary
    from odofuse.config import load_config

    sensors = tuple(load_config(logs["config"]).sensors)
    assert sensors  # the simulated config fuses GPS and ranges
    out = tmp_path / "out"
    dr = run_batch(logs["config"], logs["good"][2:], out, client, estimator="dead_reckoning")
    assert ", ".join(sensors) in dr.unfused and dr[0]["status"] == "ok"
    print_summary(dr, out)
    assert f"note: dead_reckoning fuses none of the configured sensors ({', '.join(sensors)})" in (
        capsys.readouterr().out
    )
    fused = run_batch(logs["config"], logs["good"][2:], tmp_path / "o2", client)
    assert fused.unfused is None
