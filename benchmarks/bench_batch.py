"""odofuse batch on Dask: logs/hour with 2 workers vs one process, and --split vs unsplit.

Run from any working directory::

    python benchmarks/bench_batch.py                 # 8 logs of ~1 h, a 6 h log split
    python benchmarks/bench_batch.py --long-hours 24 # the issue's 24 h log (minutes)

1. Fleet: ``--logs`` simulated logs (figure eights with GPS and beacon ranges, the smoother)
   run (a) one after another by ``odofuse run`` processes, as the shell loop a fleet operator
   uses today (each process imports gtsam and filterpy again), (b) one after another in this
   one process (imports paid once), and (c) by ``run_batch`` on a LocalCluster of 2 workers
   (start-up included). Prints logs/hour and the ratios (target c/a >= 1.6).
2. Split: one long simulated log smoothed whole in this process vs ``run_batch(split=...)`` on
   2 workers (loading, dead reckoning, windows and stitching included), and the largest
   distance between the two trajectories away from the seams (target: >= 1.6x, < 1 cm).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
BEACONS = np.array([[1, 0.0, 8.0], [2, 0.0, -8.0], [3, 12.0, 0.0], [4, -12.0, 0.0]])
LAP_S = 2 * 2 * np.pi * 5.0 / 0.5


def make_log(folder: Path, hours: float, seed: int) -> Path:
    from odofuse.teaching import simulate as sim

    laps = max(1, round(hours * 3600 / LAP_S))
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
    sim.write_log(sim.simulate(sc), folder, estimator="smoother")
    return folder


def fleet(tmp: Path, n: int, hours: float) -> None:
    from odofuse.batch import local_client, run_batch
    from odofuse.config import load_config
    from odofuse.io.loader import load_log_for
    from odofuse.rundir import run_one

    logs = [make_log(tmp / f"log{i}", hours, seed=i) for i in range(n)]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    t = time.perf_counter()
    for p in logs:
        cmd = [sys.executable, "-m", "odofuse", "run", str(p / "config.yaml"), "-o"]
        subprocess.run([*cmd, str(tmp / "loop" / p.name)], check=True, env=env, capture_output=True)
    loop = time.perf_counter() - t
    t = time.perf_counter()
    for p in logs:
        cfg = load_config(p / "config.yaml")
        run_one(cfg, load_log_for(cfg), tmp / "serial" / p.name)
    serial = time.perf_counter() - t
    t = time.perf_counter()
    client = local_client(2)
    summary = run_batch(logs[0] / "config.yaml", logs, tmp / "batch", client, progress=False)
    client.cluster.close()
    client.close()
    batch = time.perf_counter() - t
    assert not summary.failed, summary.failed
    print(f"fleet: {n} simulated logs of {hours:g} h each (smoother)")
    for name, s in (
        ("odofuse run loop", loop),
        ("one process", serial),
        ("batch, 2 workers", batch),
    ):
        print(f"  {name:18s} {s:7.1f} s  {3600 * n / s:8.0f} logs/hour")
    print(f"  speed-up 2 workers vs run loop:    {loop / batch:.2f}x (target >= 1.6)")
    print(f"  speed-up 2 workers vs one process: {serial / batch:.2f}x")


def split(tmp: Path, hours: float, window: float) -> None:
    from odofuse.batch import local_client, run_batch
    from odofuse.config import load_config
    from odofuse.estimators import run_estimator
    from odofuse.io.loader import load_log_for
    from odofuse.outputs import read_trajectory_csv
    from odofuse.trajectory import interpolate_poses

    folder = make_log(tmp / "long", hours, seed=99)
    cfg = load_config(folder / "config.yaml")
    run_estimator(
        "smoother", load_log_for(load_config(make_log(tmp / "w", 0.05, 1) / "config.yaml")), cfg
    )
    t = time.perf_counter()
    log = load_log_for(cfg)
    whole = run_estimator("smoother", log, cfg).trajectory
    unsplit = time.perf_counter() - t
    client = local_client(2)
    client.run(__import__, "gtsam")
    t = time.perf_counter()
    summary = run_batch(cfg, [folder], tmp / "split", client, split=window, progress=False)
    took = time.perf_counter() - t
    client.cluster.close()
    client.close()
    assert not summary.failed, summary.failed
    meta = json.loads((tmp / "split" / "long" / "metrics.json").read_text(encoding="utf-8"))
    info = meta["extra"]["split"]
    w = info["windows"][1] if len(info["windows"]) > 1 else info["windows"][0]
    overlap = w["core_start"] - w["start"]
    stitched = read_trajectory_csv(tmp / "split" / "long" / "trajectory.csv")
    d = interpolate_poses(whole, stitched.t) - stitched.poses
    err = np.hypot(d[:, 0], d[:, 1])
    seams = np.array([s["t"] for s in info["seams"]])
    away = np.all(np.abs(stitched.t[:, None] - seams[None, :]) > overlap, axis=1)
    print(f"split: one {hours:g} h simulated log, windows of {window:g} s, overlap {overlap:g} s")
    print(f"  unsplit smoother (one process, load included): {unsplit:7.1f} s")
    print(f"  --split on 2 workers ({len(info['windows'])} windows, all included): {took:7.1f} s")
    print(f"  speed-up: {unsplit / took:.2f}x (target >= 1.6)")
    print(f"  stitched vs unsplit, away from the seams: max {1e3 * err[away].max():.3f} mm")
    print(f"  stitched vs unsplit, everywhere: max {1e3 * err.max():.3f} mm")
    worst = max((s["max_position_diff_m"] for s in info["seams"]), default=0.0)
    print(f"  largest window disagreement over an overlap: {1e3 * worst:.1f} mm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=8)
    ap.add_argument("--hours", type=float, default=1.0, help="length of each fleet log")
    ap.add_argument("--long-hours", type=float, default=6.0, help="length of the split log")
    ap.add_argument("--window", type=float, default=3600.0, help="--split window, s")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        fleet(Path(d), args.logs, args.hours)
        split(Path(d), args.long_hours, args.window)


if __name__ == "__main__":
    main()
