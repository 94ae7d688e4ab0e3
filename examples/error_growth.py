"""Odometry error growth: Siegwart's linearised covariance against a Monte-Carlo cloud.

The story
---------
Siegwart & Nourbakhsh (ch. 5) propagate the pose covariance of a differential robot through
one odometry step as ``Sigma_p' = F_p Sigma_p F_p^T + F_rl Sigma_rl F_rl^T`` with wheel-travel
variances ``k |ds|``. That is a linearisation: it draws an ellipse. The true distribution of
poses after a long straight run is a banana, curved because the heading error turns the
direction of travel.

This script drives the same 5 m straight line N times in the simulator with random wheel slip
(same seeded generator for every run), dead-reckons it once with the linearised covariance
(:func:`odofuse.motion.dead_reckon`) and compares the two with the normalised estimation error
squared, ``NEES = e^T P^-1 e``. For a consistent model the mean NEES of N runs lies within
the chi-square bounds around 3; for moderate wheel noise it does, for large heading noise it
does not, and the picture (written by :func:`odofuse.teaching.demos.demo_error_growth`) shows why.

Run ``python examples/error_growth.py --out growth-out`` (``--quick``: 200 runs).
"""

from __future__ import annotations

import argparse

import numpy as np

from odofuse import se2
from odofuse.drives import make_drive
from odofuse.motion import MotionModel, OdometryErrorModel, dead_reckon
from odofuse.teaching.demos import demo_error_growth, nees_bounds
from odofuse.teaching.simulate import Scenario, WheelNoise, simulate


def mean_nees(k: float, runs: int, seed: int) -> tuple[float, float]:
    """Mean NEES at the end of a 5 m straight run, and the final heading sigma (rad)."""
    geometry = {"wheel_radius": 0.04, "track_width": 0.235}
    scenario = Scenario(
        geometry=geometry,
        dt=0.05,
        wheel_noise=WheelNoise(k=k),
        path={"kind": "twists", "values": [[0.0, 0.05, 0.0]] * 100},
    )
    sims = [simulate(scenario, seed=seed + i) for i in range(runs)]
    model = MotionModel(
        make_drive("differential", **geometry), OdometryErrorModel((k, k), (0.0, 0.0)), "rk2"
    )
    poses, covs = dead_reckon(model, np.zeros(3), np.zeros((3, 3)), sims[0].u_meas)
    errors = np.array([s.truth[-1] - poses[-1] for s in sims])
    errors[:, 2] = se2.wrap(errors[:, 2])
    nees = np.einsum("ri,ij,rj->r", errors, np.linalg.inv(covs[-1]), errors)
    return float(nees.mean()), float(np.sqrt(covs[-1][2, 2]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="growth-out", help="output folder for the picture")
    parser.add_argument("--quick", action="store_true", help="200 Monte-Carlo runs")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    runs = 200 if args.quick else 1000
    lo, hi = nees_bounds(runs)
    print(f"{runs} runs: mean NEES of a consistent model lies in [{lo:.2f}, {hi:.2f}]")
    print(f"{'k [m^2/m]':>10s} {'sigma_theta [rad]':>18s} {'mean NEES':>10s}  verdict")
    for k in (5e-7, 1e-5, 2.5e-3):
        nees, sig = mean_nees(k, runs, args.seed)
        verdict = "consistent" if lo <= nees <= hi else "linearisation breaks down"
        print(f"{k:10.1e} {sig:18.3f} {nees:10.2f}  {verdict}")
    result = demo_error_growth(args.out, quick=args.quick, seed=args.seed)
    print(f"picture: {result['png']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
