"""The EKF and UKF with a gyro as a user configures them (robust odometry on, the default):
the compiled core against the Python path, as ratios measured in this process.

Run from any directory: ``python /path/to/benchmarks/bench_slip.py [--hours H]
[--repeats R]``. On the figure eight of ``tests/compiled_checks.py`` with its wheel slip
bursts (``SLIP_SCENARIO``; differential drive at 50 Hz, a biased gyro at 25 Hz, GPS, compass,
ranges; laps from ``--hours``, default 0.1 h) and each filter's config with
``odometry_calibration: true`` and ``slip`` left at its default: each filter's whole offline
run (``odofuse.estimators.ekf.run`` / ``ukf.run``) with ``compiled: on`` (best of ``R``)
and ``off`` (once: the Python EKF, the filterpy UKF), their ratio, the slipping steps of each
and the largest pose and covariance differences. Until session 24 a run with a gyro took the
Python path whatever ``compiled`` said. A warm-up run keeps compilation out of the timings.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # _timing, bench_compiled

import numpy as np  # noqa: E402
from _timing import best_of  # noqa: E402, F401 - puts the repository first on sys.path
from bench_compiled import best, load  # noqa: E402
from bench_compiled_ukf import with_options  # noqa: E402

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests")
)
from compiled_checks import SLIP_SCENARIO  # noqa: E402


def figure_eight(hours: float, seed: int = 3):
    """The slip scenario for ``hours`` and the EKF's and UKF's configs (``slip`` default)."""
    from odofuse.config import config_from_dict
    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import run_config, to_sensor_log
    from odofuse.teaching.simulate import simulate

    laps = max(1, round(hours * 3600.0 / 75.4))  # one lap: 2 x 2 pi 3 m at 0.5 m/s
    sc = {**SLIP_SCENARIO, "path": {**SLIP_SCENARIO["path"], "laps": laps}}
    sim = simulate(scenario_from_dict(sc, "<bench>"), seed=seed)
    cfgs = []
    for name in ("ekf", "ukf"):
        d = run_config(sim, name)
        d["options"] = {name: {"odometry_calibration": True}}
        cfgs.append(dataclasses.replace(config_from_dict(d, "<bench>"), log="<memory>"))
    return to_sensor_log(sim), cfgs


def main(argv=None) -> dict:
    from odofuse.estimators import ekf, ukf

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=0.1)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    print(f"bench_slip: {load()}")
    log, cfgs = figure_eight(args.hours)
    steps = len(log.streams["wheels"]) - 1
    print(f"figure eight with slip bursts, {args.hours:g} h ({steps} odometry steps)")
    rows = {}
    for cfg, mod in zip(cfgs, (ekf, ukf), strict=True):
        name = cfg.estimator
        on = with_options(cfg, name, compiled="on")
        off = with_options(cfg, name, compiled="off")
        res = mod.run(log, on)  # warm-up (compiles on a fresh cache)
        (t_on,) = best([lambda on=on, mod=mod: mod.run(log, on)], args.repeats)
        t0 = time.perf_counter()
        ref = mod.run(log, off)
        t_off = time.perf_counter() - t0
        rows[name] = r = {
            "compiled": t_on,
            "python": t_off,
            "ratio": t_off / t_on,
            "slip steps": (res.extra.get("slip_steps"), ref.extra.get("slip_steps")),
            "pose": float(np.abs(res.trajectory.poses - ref.trajectory.poses).max()),
            "cov": float(np.abs(res.trajectory.covariances - ref.trajectory.covariances).max()),
        }
        print(
            f"  {name}: compiled {r['compiled']:.3f} s, Python {r['python']:.2f} s "
            f"({r['ratio']:.0f}x); slipping steps {r['slip steps'][0]} / {r['slip steps'][1]}; "
            f"largest differences: poses {r['pose']:.1e}, covariances {r['cov']:.1e}"
        )
    return rows


if __name__ == "__main__":
    main()
