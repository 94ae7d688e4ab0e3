"""How often the geometry advice (``odofuse.status.geometry``) names a wrong wheel radius or track.

Run from any directory: ``python benchmarks/bench_geometry_advice.py [--seeds N] [--first S]
[--estimators ...] [--laps L]``.

The status benchmark's logs (``bench_status.make_case``: about 94 s a lap, ``--laps`` of them
(default 1), a differential robot with
a gyro and 1 Hz GPS at sigma 0.5 m or 2 m, the config a user writes) with the wheel radius or
the track 3 % off (``wheel_radius_3pct``, ``track_width_3pct``), the real robot's logs (radius
2.5 % off, gyro bias 3 mrad/s, three gross fixes) and the nominal ``gyro_gps`` logs (``E_d``,
``E_b`` drawn at sigma 0.2 %, radius and track exact). Each estimator runs as
``odofuse.rundir.estimate`` runs it (no second opinion: the advice reads the run's own
calibration). Printed per kind and estimator: the runs advising the radius (``robot.wheel_radius``)
and the track (``robot.track_width``), and the median ``|z|`` of the faulty state with its
median sigma: a state advises at ``|z| > 3.29``, so a fault of size ``d`` is advised about half
the time when ``d`` is 3.29 sigma and 95 % of the time at 4.9 sigma (the minimal detectable
error at 95 % power). The advised radius ratios are scored against the simulator's ``E_d``
(within 3.29 of their sigmas); ground truth is not read otherwise.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import bench_status as bs  # noqa: E402

from odofuse.status.geometry import calibration_estimates, geometry_advice  # noqa: E402

KINDS = ("wheel_radius_3pct", "track_width_3pct", bs.REAL_ROBOT, None)
STATE = {"wheel_radius_3pct": "wheel_radius_scale", "track_width_3pct": "track_width_scale"}
STATE[bs.REAL_ROBOT] = "wheel_radius_scale"
SHORT = {"wheel_radius_scale": "Es", "wheel_radius_ratio": "Ed", "track_width_scale": "Eb"}


def nominal_seeds(first: int, n: int) -> list[int]:
    """The first ``n`` seeds from ``first`` whose nominal log is differential with gyro and GPS."""
    out, s = [], first
    while len(out) < n:
        if bs.nominal_combination(s)[:2] == ("differential", "gyro_gps"):
            out.append(s)
        s += 1
    return out


def cases(seeds: int, first: int):
    """``(kind, seed)`` of every log: ``seeds`` per kind of :data:`KINDS` from ``first`` (the
    nominal kind, None, from :func:`nominal_seeds`)."""
    for kind in KINDS:
        picked = nominal_seeds(first, seeds) if kind is None else range(first, first + seeds)
        for seed in picked:
            yield kind, seed


def run(seeds: int, first: int, estimators) -> dict:
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.rundir import estimate

    table = {}
    for kind, seed in cases(seeds, first):
        t0 = time.perf_counter()
        log, cfg, what = bs.make_case(seed, kind)
        sc = bs.case_scenario(seed, kind)[0]
        true_ratio = sc["systematic"].get("E_d", 1.0)  # scores the advice, chooses nothing
        cfg, log = apply_log_defaults(cfg, log)
        brief = []
        for est in estimators:
            result, _ = estimate(dataclasses.replace(cfg, estimator=est), log, None)
            extra = result.extra or {}
            advice = geometry_advice(cfg.robot, extra)
            cal = calibration_estimates(extra)
            z = {n: (v - m) / s for n, (v, s, m) in cal.items()}
            row = table.setdefault((kind or "nominal", est), [])
            row.append(
                {
                    "radius": any("`robot.wheel_radius`" in a for a in advice),
                    "track": any("`robot.track_width`" in a for a in advice),
                    "ratio": any("`robot.wheel_radius_left:" in a for a in advice),
                    "ratio_error": (
                        (cal["wheel_radius_ratio"][0] - true_ratio) / cal["wheel_radius_ratio"][1]
                        if "wheel_radius_ratio" in cal
                        else np.nan
                    ),
                    "z": z,
                    "sigma": {n: s for n, (_, s, _) in cal.items()},
                }
            )
            brief.append(f"{est}:" + ",".join(f"{SHORT.get(n, n)}{v:+.1f}" for n, v in z.items()))
        dt = time.perf_counter() - t0
        print(f"  {kind or 'nominal'} {seed} {what} ({dt:.0f} s): {' '.join(brief)}")
        sys.stdout.flush()
    return table


def summary(table) -> list[str]:
    lines = [
        "| logs | estimator | advise the radius | advise the track | advise the radius ratio "
        "(of them within 3.29 sigma of the simulated E_d) "
        "| faulty state: median abs(z) | its median sigma |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for (kind, est), rows in table.items():
        n = len(rows)
        radius, track = sum(r["radius"] for r in rows), sum(r["track"] for r in rows)
        ratio = sum(r["ratio"] for r in rows)
        # the advised ratios against the simulated E_d: within 3.29 of their sigmas
        right = sum(r["ratio"] and abs(r["ratio_error"]) <= 3.29 for r in rows)
        state = STATE.get(kind)
        if state is not None:
            zs = [abs(r["z"][state]) for r in rows if state in r["z"]]
            sd = [r["sigma"][state] for r in rows if state in r["sigma"]]
            zcol = f"{np.median(zs):.2f} ({state})" if zs else "-"
            sdcol = f"{np.median(sd):.4f}" if sd else "-"
        else:
            zcol = sdcol = "-"
        lines.append(
            f"| {kind} | {est} | {radius}/{n} | {track}/{n} | {ratio}/{n} ({right}) | {zcol} "
            f"| {sdcol} |"
        )
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="logs per kind (default 20)")
    ap.add_argument("--first", type=int, default=9200, help="first seed (default 9200)")
    ap.add_argument(
        "--estimators", nargs="*", default=["ekf", "ukf", "smoother"], choices=bs.ESTIMATORS
    )
    ap.add_argument(
        "--laps", type=int, default=1, help="laps of each log's path (default 1: about 94 s)"
    )
    args = ap.parse_args(argv)
    bs.LAPS = args.laps
    t0 = time.perf_counter()
    table = run(args.seeds, args.first, args.estimators)
    print("\n".join(summary(table)))
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
