"""Simulate a robot, write a log folder, and compare dead reckoning with an EKF.

The story
---------
A differential-drive robot (4 cm wheels, 23.5 cm track) drives a figure eight. Its right wheel
is 0.2 % larger than its left one and its true wheelbase 0.5 % longer than the nominal value
(systematic errors); its wheels also slip randomly (non-systematic errors, Siegwart's
``k |ds|`` model). It carries a gyro and a GPS receiver that drops out for 40 s.

1. :func:`odofuse.teaching.simulate.simulate` produces the truth and every sensor stream from one
   seed.
2. :func:`odofuse.teaching.simulate.write_log` writes the log folder of the public spec, including
   ``groundtruth.csv`` and a ``config.yaml`` for ``odofuse run``.
3. The folder is read back like any recorded log, and two estimators run on it: dead
   reckoning (wheels only) and the EKF (wheels + gyro + GPS).
4. The absolute trajectory error shows what fusion buys: odometry drifts without bound, the
   EKF stays within about a metre even through the outage.

Run ``python examples/simulate_and_fuse.py --out sim-out`` (add ``--quick`` for a short run).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from odofuse.config import load_config
from odofuse.estimators import run_estimator
from odofuse.evaluation import ate, trajectory_from_stream
from odofuse.io.loader import load_log_for
from odofuse.teaching.simulate import (
    EncoderSpec,
    GpsSpec,
    GyroSpec,
    Scenario,
    SystematicErrors,
    WheelNoise,
    simulate,
    write_log,
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="sim-out", help="output folder")
    parser.add_argument("--quick", action="store_true", help="one short lap")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)

    scenario = Scenario(
        drive="differential",
        geometry={"wheel_radius": 0.04, "track_width": 0.235},
        path={"kind": "figure_eight", "radius": 4.0, "speed": 0.5, "laps": 1 if args.quick else 2},
        dt=0.05 if args.quick else 0.02,
        systematic=SystematicErrors(E_d=1.002, E_b=1.005),
        wheel_noise=WheelNoise(k=1e-5),
        encoder=EncoderSpec(ticks_per_rev=979.2, rollover=65536),
        gyro=GyroSpec(sigma=0.01, rate=10.0),
        gps=GpsSpec(sigma=1.0, rate=1.0, outages=((30.0, 70.0),)),
        seed=args.seed,
    )
    sim = simulate(scenario)
    log_dir = Path(args.out) / "log"
    write_log(sim, log_dir)
    print(f"wrote {log_dir} ({len(sim.t)} wheel rows, {len(sim.streams['gps'])} GPS fixes)")

    config = load_config(log_dir / "config.yaml")
    log = load_log_for(config)
    truth = trajectory_from_stream(log.groundtruth)
    print(f"{'estimator':16s} {'ATE rmse [m]':>13s} {'final [m]':>10s}")
    for name, sensors in (("dead_reckoning", {}), ("ekf", config.sensors)):
        result = run_estimator(name, log, replace(config, estimator=name, sensors=sensors))
        err = ate(result.trajectory, truth)
        print(f"{name:16s} {err.rmse_m:13.3f} {err.final_m:10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
