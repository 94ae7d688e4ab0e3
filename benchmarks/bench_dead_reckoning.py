"""Dead-reckoning throughput for 10^6 increments, as ratios to a plain Python loop.

Run: ``python benchmarks/bench_dead_reckoning.py [--steps N]``. Prints increments per second of
the vectorised pose-only path, the vectorised path with covariance, the step-by-step
``MotionModel.predict`` loop and a plain-Python (math module) pose loop, all measured in this
process on the same inputs, and the ratios between them. Targets (issue "Core"): pose-only
>= 1e7 increments/s, with covariance >= 1e6 increments/s.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from _timing import best_of

from odofuse.drives import Differential
from odofuse.motion import MotionModel, OdometryErrorModel, dead_reckon


def python_loop(U, r, b):
    """The plain loop a newcomer writes: exact arc integration with the math module."""
    x = y = th = 0.0
    for ul, ur in U.tolist():
        ds, dth = r * (ur + ul) / 2, r * (ur - ul) / b
        if abs(dth) > 1e-12:
            rc = ds / dth
            x += rc * (math.sin(th + dth) - math.sin(th))
            y -= rc * (math.cos(th + dth) - math.cos(th))
        else:
            x += ds * math.cos(th)
            y += ds * math.sin(th)
        th += dth
    return x, y, th


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--loop-steps", type=int, default=100_000)
    args = parser.parse_args(argv)
    r, b = 0.05, 0.3
    model = MotionModel(Differential(r, b), OdometryErrorModel((1e-4, 1e-4), (0.0, 0.0)), "exact")
    U = np.random.default_rng(0).normal(1.0, 0.5, (args.steps, 2))
    pose0, P0 = np.zeros(3), np.eye(3) * 1e-4
    n_loop = min(args.loop_steps, args.steps)

    def predict_loop():
        pose, P = pose0, P0
        for u in U[:n_loop]:
            pose, P, _, _ = model.predict(pose, P, u)

    def vectorised(with_cov):
        return lambda: dead_reckon(model, pose0, P0, U, with_cov)

    rates = {
        "vectorised pose-only": args.steps / best_of(vectorised(False)),
        "vectorised with covariance": args.steps / best_of(vectorised(True)),
        "plain Python loop (pose only)": n_loop / best_of(lambda: python_loop(U[:n_loop], r, b), 1),
        "MotionModel.predict loop (with cov)": n_loop / best_of(predict_loop, 1),
    }
    base = rates["plain Python loop (pose only)"]
    print(f"{'path':40s} {'increments/s':>14s} {'x plain loop':>13s}")
    for name, rate in rates.items():
        print(f"{name:40s} {rate:14.3g} {rate / base:13.1f}")
    for name, target in (("vectorised pose-only", 1e7), ("vectorised with covariance", 1e6)):
        verdict = "met" if rates[name] >= target else "NOT met"
        print(f"target {name} >= {target:.0e}/s: {verdict}")
    return rates


if __name__ == "__main__":
    main()
