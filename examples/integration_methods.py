"""Euler, Runge-Kutta 2 and exact odometry integration against the step size.

The story
---------
The Politecnico slides integrate a differential drive with constant ``v`` and ``omega`` over
each sampling period in three ways: Euler (move along the heading at the step start), second
order Runge-Kutta (move along the *mid-step* heading) and the exact arc about the
instantaneous centre of rotation. On a circle the exact one is exact for any step, RK2's
error shrinks with the square of the step and Euler's only linearly.

This script integrates a half circle (radius 1 m) with :func:`odofuse.motion.integrate` for
a range of step sizes, prints the final position errors and the fitted convergence orders, and
writes the slide picture with :func:`odofuse.teaching.demos.demo_integration`.

Run ``python examples/integration_methods.py --out integration-out`` (``--quick``: fewer steps).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from odofuse.motion import integrate
from odofuse.teaching.demos import demo_integration


def final_error(method: str, n_steps: int, v: float = 0.5, w: float = 0.5) -> float:
    """Position error (m) after a half circle integrated in ``n_steps`` steps."""
    T = math.pi / w
    twist = np.array([w, v, 0.0]) * (T / n_steps)  # [omega, v_x, v_y] over one step
    pose = np.zeros(3)
    for _ in range(n_steps):
        pose = integrate(pose, twist, method)[0]
    R = v / w
    return float(np.hypot(pose[0] - 0.0, pose[1] - 2 * R))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="integration-out", help="output folder")
    parser.add_argument("--quick", action="store_true", help="fewer step sizes")
    args = parser.parse_args(argv)
    steps = [4, 16, 64] if args.quick else [4, 8, 16, 32, 64, 128, 256]
    print(f"{'steps':>6s} {'euler [m]':>12s} {'rk2 [m]':>12s} {'exact [m]':>12s}")
    table = {m: [final_error(m, n) for n in steps] for m in ("euler", "rk2", "exact")}
    for i, n in enumerate(steps):
        print(f"{n:6d} {table['euler'][i]:12.3e} {table['rk2'][i]:12.3e} {table['exact'][i]:12.3e}")
    for m in ("euler", "rk2"):
        order = np.polyfit(np.log(1.0 / np.array(steps)), np.log(table[m]), 1)[0]
        print(f"{m}: error ~ dt^{order:.2f}")
    result = demo_integration(args.out, quick=args.quick)
    print(f"picture: {result['png']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
