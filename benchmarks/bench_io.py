"""End-to-end I/O benchmark: a 10 h, 50 Hz log through ``odofuse run`` against the I/O floor.

Run from any directory: ``python benchmarks/bench_io.py [--hours H] [--code DIR]``
(``--code``: the odofuse source tree to time, default the one this script belongs to; so the
same script times an older checkout for a before/after comparison).

* The log (``odometry.csv`` ds/dtheta at 50 Hz, ``gps.csv`` at 1 Hz, ``groundtruth.csv`` at
  50 Hz; seeded numpy) is generated once into ``/tmp/odofuse-bench-io-<hours>h`` (never into the
  repository) with two run configs, dead reckoning and EKF (odometry + GPS).
* **I/O floor**: plain numpy in a subprocess, ``np.loadtxt`` of every log file and
  ``np.savetxt`` of a trajectory of the log's size (10 columns, ``%.17g``) -- what reading the
  log and writing the trajectory costs without odofuse.
* ``odofuse run`` end to end (a fresh subprocess each, wall time and peak resident memory
  from ``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``), and the same run split into its
  phases (load, estimate, metrics, write csv/tum/json, plot) in another subprocess.

Prints a table of times and their ratios to the floor (targets: dead reckoning within 3x,
EKF within 5x, peak memory below 600 MB). Asserts nothing.
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

REPO = Path(__file__).resolve().parents[1]
RATE = 50.0

_FLOOR = r"""
import sys, time, numpy as np, resource
from pathlib import Path
t0 = time.perf_counter()
n = 0
for f in sorted(Path(sys.argv[1]).glob("*.csv")):
    a = np.loadtxt(f, delimiter=",", skiprows=1, ndmin=2)
    n = max(n, len(a))
t1 = time.perf_counter()
np.savetxt(sys.argv[2], np.random.default_rng(0).normal(size=(n, 10)), fmt="%.17g",
           delimiter=",", header="t,x,y,theta,var_x,cov_xy,cov_xtheta,var_y,cov_ytheta,var_theta",
           comments="")
t2 = time.perf_counter()
print(t1 - t0, t2 - t1)
"""

_PHASES = r"""
import json, sys, time, resource
from pathlib import Path
t = {}
s = time.perf_counter()
from odofuse.config import load_config
from odofuse.io.loader import load_log_for
from odofuse.log_defaults import apply_log_defaults
from odofuse.estimators import run_estimator
from odofuse.evaluation import metrics
from odofuse import outputs
t["import"] = time.perf_counter() - s
config = load_config(sys.argv[1])
out = Path(sys.argv[2]); out.mkdir(parents=True, exist_ok=True)
s = time.perf_counter(); log = load_log_for(config); t["load"] = time.perf_counter() - s
config, log = apply_log_defaults(config, log)
s = time.perf_counter()
res = run_estimator(config.estimator, log, config)
t["estimate"] = time.perf_counter() - s
s = time.perf_counter(); m = metrics(res, log, 0.0); t["metrics"] = time.perf_counter() - s
s = time.perf_counter()
outputs.write_trajectory_csv(out / "trajectory.csv", res.trajectory)
outputs.write_tum(out / "trajectory.tum", res.trajectory)
outputs.write_metrics(out / "metrics.json", m)
t["write"] = time.perf_counter() - s
s = time.perf_counter()
from odofuse.plotting import plot_run
plot_run(out / "trajectory.png", res, log)
t["plot"] = time.perf_counter() - s
t["rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(t))
"""


def make_log(hours: float, seed: int = 0) -> Path:
    """Write (once) the simulated log folder and its two configs; returns the folder."""
    folder = Path(tempfile.gettempdir()) / f"odofuse-bench-io-{hours:g}h"
    if (folder / "ekf.yaml").exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    n = int(round(hours * 3600 * RATE))
    dt = 1.0 / RATE
    t = np.arange(1, n + 1) * dt
    ds = np.full(n, 0.8 * dt)
    dth = 0.3 * dt * np.sin(2 * np.pi * t / 90.0)
    theta = np.cumsum(dth) - dth / 2
    xy = np.cumsum(np.column_stack([ds * np.cos(theta), ds * np.sin(theta)]), axis=0)
    heading = np.angle(np.exp(1j * np.cumsum(dth)))
    odo = np.column_stack([t, ds + rng.normal(0, 1e-4, n), dth + rng.normal(0, 1e-4, n)])
    g = np.arange(int(RATE) - 1, n, int(RATE))
    gps = np.column_stack([t[g], xy[g] + rng.normal(0, 0.5, (g.size, 2))])
    gt = np.column_stack([t, xy, heading])
    for name, arr, head in (
        ("odometry", odo, "t,ds,dtheta"),
        ("gps", gps, "t,x,y"),
        ("groundtruth", gt, "t,x,y,theta"),
    ):
        tmp = folder / f".{name}.csv"
        np.savetxt(tmp, arr, fmt="%.10g", delimiter=",", header=head, comments="")
        tmp.replace(folder / f"{name}.csv")
    common = (
        f"log: {folder}\nrobot: {{drive: increments}}\n"
        "motion: {integrator: exact, k: [1.0e-4, 1.0e-4]}\n"
        "initial: {pose: [0, 0, 0], sigma: [0.1, 0.1, 0.05]}\n"
    )
    (folder / "dead_reckoning.yaml").write_text(common + "estimator: dead_reckoning\n")
    (folder / "ekf.yaml").write_text(common + "estimator: ekf\nsensors: {gps: {sigma: 0.5}}\n")
    return folder


_WRAP = (
    "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); "
    "sys.exit(r.returncode)"
)


def _child(args: list[str], code: Path) -> tuple[float, float, str]:
    """Run ``python args`` in a fresh process; returns (wall s, peak RSS MB, stdout).

    The peak is ``ru_maxrss`` of the children of a one-child wrapper process, i.e. of this run
    alone.
    """
    env = {**os.environ, "PYTHONPATH": str(code), "MPLBACKEND": "Agg"}
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _WRAP, sys.executable, *args],
        env=env,
        capture_output=True,
        text=True,
        cwd=tempfile.gettempdir(),
    )
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"child failed: {' '.join(args)}\n{proc.stderr[-2000:]}")
    peak = int(proc.stderr.strip().splitlines()[-1]) / 1024  # KiB -> MiB
    return wall, peak, proc.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=10.0)
    ap.add_argument("--code", type=Path, default=REPO, help="odofuse source tree to time")
    ap.add_argument("--skip", default="", help="comma list of estimators not to run")
    a = ap.parse_args()
    folder = make_log(a.hours)
    size = sum(f.stat().st_size for f in folder.glob("*.csv")) / 1e6
    rows = sum(1 for _ in open(folder / "odometry.csv")) - 1
    arrays = sum(
        (sum(1 for _ in open(f)) - 1) * (open(f).readline().count(",") + 1)
        for f in folder.glob("*.csv")
    )
    print(
        f"log {folder}: {rows} odometry rows, {size:.0f} MB of CSV, "
        f"{arrays * 8 / 1e6:.0f} MB as float64 arrays; code {a.code}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        wall, peak, out = _child(["-c", _FLOOR, str(folder), f"{tmp}/floor.csv"], a.code)
        read_s, write_s = (float(v) for v in out.split())
        floor = read_s + write_s
        print(
            f"I/O floor (numpy loadtxt + savetxt): {floor:.2f} s (read {read_s:.2f}, write "
            f"{write_s:.2f}); process {wall:.2f} s"
        )
        print(
            f"{'estimator':16s} {'wall s':>7s} {'x floor':>8s} {'peak MB':>8s} | phases s: "
            "import load estimate metrics write plot"
        )
        for est in ("dead_reckoning", "ekf"):
            if est in a.skip.split(","):
                continue
            cfg = str(folder / f"{est}.yaml")
            wall, peak, _ = _child(["-m", "odofuse", "run", cfg, "-o", f"{tmp}/{est}"], a.code)
            _, _, ph = _child(["-c", _PHASES, cfg, f"{tmp}/{est}-phases"], a.code)
            p = json.loads(ph)
            split = " ".join(
                f"{p[k]:.2f}" for k in ("import", "load", "estimate", "metrics", "write", "plot")
            )
            print(
                f"{est:16s} {wall:7.2f} {wall / floor:8.2f} {peak:8.0f} | {split} "
                f"(phases process peak {p['rss_mb']:.0f} MB)"
            )
    print("targets: dead reckoning <= 3x floor, EKF <= 5x floor, peak memory < 600 MB")


if __name__ == "__main__":
    main()
