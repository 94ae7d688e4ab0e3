"""The compiled offline UKF against the compiled offline EKF, as ratios measured in this
process (issue 28 item 1: the UKF within 3x of the EKF on Plaza1 and on a 1 h log).

Run from any directory: ``python /path/to/benchmarks/bench_compiled_ukf.py [--repeats R]
[--hours H] [--python]``. Prints, for Plaza1 (the builtin default dataset, its packaged
``plaza1-ekf.yaml`` / ``plaza1-ukf.yaml``) and a simulated figure eight of ``H`` hours
(differential drive at 50 Hz, a biased gyro at 25 Hz, GPS, compass, ranges to four beacons,
odometry calibration on, ``slip: false`` as when robust odometry was not compiled, so that
the figures stay comparable; ``bench_slip.py`` times it on): the
whole offline run of each filter (``odofuse.estimators.ekf.run`` / ``ukf.run``: assembly, the
kernel, the result and its findings), best of ``R`` interleaved, and their ratio. The
filterpy UKF (``compiled: off``) is timed once on Plaza1 and, with ``--python``, on the long
log (minutes), where its result is also compared with the compiled one's.

The first run on a machine compiles the kernels (cached on disk afterwards); a warm-up run
keeps compilation out of the timings.
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

#: The figure eight of ``tests/compiled_checks.py`` (the compiled-core tests' scenario);
#: ``laps`` set from ``--hours``.
sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests")
)
from compiled_checks import SCENARIO  # noqa: E402


def with_options(cfg, estimator, **options):
    opts = dataclasses.replace(cfg.estimator_options(estimator), **options)
    return dataclasses.replace(cfg, estimator=estimator, options={**cfg.options, estimator: opts})


def plaza1():
    from odofuse.config import load_config
    from odofuse.io.loader import load_log_for

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cfgs = os.path.join(root, "odofuse", "default_configs")
    ekf = load_config(os.path.join(cfgs, "plaza1-ekf.yaml"))
    ukf = load_config(os.path.join(cfgs, "plaza1-ukf.yaml"))
    return load_log_for(ekf), ekf, ukf


def figure_eight(hours: float, seed: int = 3):
    from odofuse.config import config_from_dict
    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import run_config, to_sensor_log
    from odofuse.teaching.simulate import simulate

    laps = max(1, round(hours * 3600.0 / 75.4))  # one lap: 2 x 2 pi 3 m at 0.5 m/s
    sc = {**SCENARIO, "path": {**SCENARIO["path"], "laps": laps}}
    sim = simulate(scenario_from_dict(sc, "<bench>"), seed=seed)
    log = to_sensor_log(sim)
    out = []
    for name in ("ekf", "ukf"):
        d = run_config(sim, name)
        d["options"] = {name: {"odometry_calibration": True, "slip": False}}
        out.append(dataclasses.replace(config_from_dict(d, "<bench>"), log="<memory>"))
    return log, *out


def compare(log, ekf_cfg, ukf_cfg, repeats, python):
    """Row of the table: times (s) and the UKF/EKF ratio; the filterpy UKF when asked."""
    from odofuse.estimators import ekf, ukf
    from odofuse.estimators.compiled import ekf as cekf
    from odofuse.estimators.compiled import ukf as cukf

    ekf_cfg = with_options(ekf_cfg, "ekf", compiled="on")
    ukf_cfg = with_options(ukf_cfg, "ukf", compiled="on")
    assert cekf.run(log, ekf_cfg) is not None and cukf.run(log, ukf_cfg) is not None  # warm
    t_ekf, t_ukf = best([lambda: ekf.run(log, ekf_cfg), lambda: ukf.run(log, ukf_cfg)], repeats)
    row = {"ekf": t_ekf, "ukf": t_ukf, "ratio": t_ukf / t_ekf}
    if python:
        off = with_options(ukf_cfg, "ukf", compiled="off")
        t0 = time.perf_counter()
        ref = ukf.run(log, off)
        row["filterpy"] = time.perf_counter() - t0
        res = ukf.run(log, ukf_cfg)
        row["max |pose diff|"] = float(np.abs(res.trajectory.poses - ref.trajectory.poses).max())
        row["max |cov diff|"] = float(
            np.abs(res.trajectory.covariances - ref.trajectory.covariances).max()
        )
        row["same counts"] = res.used == ref.used and res.rejected == ref.rejected
    return row


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--python", action="store_true", help="also the filterpy UKF on the long log")
    args = ap.parse_args(argv)
    print(f"bench_compiled_ukf: {load()}")
    rows = {}
    log, ekf_cfg, ukf_cfg = plaza1()
    n = len(next(iter(log.streams.values())))
    rows[f"Plaza1 ({n} odometry steps)"] = compare(log, ekf_cfg, ukf_cfg, args.repeats, True)
    t0 = time.perf_counter()
    log, ekf_cfg, ukf_cfg = figure_eight(args.hours)
    steps = len(log.streams["wheels"]) - 1
    readings = sum(len(s) for k, s in log.streams.items() if k != "wheels")
    print(f"simulated {args.hours:g} h in {time.perf_counter() - t0:.1f} s")
    name = f"figure eight {args.hours:g} h ({steps} steps, {readings} readings)"
    rows[name] = compare(log, ekf_cfg, ukf_cfg, args.repeats, args.python)
    for name, r in rows.items():
        verdict = "met" if r["ratio"] <= 3 else "NOT met"
        print(f"{name}:")
        print(
            f"  compiled EKF {r['ekf']:.3f} s, compiled UKF {r['ukf']:.3f} s: "
            f"UKF/EKF {r['ratio']:.2f} (target <= 3: {verdict})"
        )
        if "filterpy" in r:
            print(
                f"  filterpy UKF {r['filterpy']:.2f} s ({r['filterpy'] / r['ukf']:.0f}x the "
                f"compiled); compiled vs filterpy: poses {r['max |pose diff|']:.1e}, "
                f"covariances {r['max |cov diff|']:.1e}, counts equal: {r['same counts']}"
            )
    return rows


if __name__ == "__main__":
    main()
