"""A measured lead for issue 25's gyro bias step: does a filter's calibration estimate move
more than its own updates explain? (docs/trust.md, "A lead for the bias step"; not a check
of odofuse, a probe of one.)

Run from any directory: ``python benchmarks/bench_calibration_drift.py [--nominal S ...]
[--faulty S ...] [--grid SECONDS] [--alpha A] [--estimator ekf]``.

A constant's estimate in a Kalman filter is a martingale: its change between two times has
the variance that the updates in between explained, ``P(t1) - P(t2) + w^2 (t2 - t1)`` with
``w`` the state's declared random walk per sqrt(s). So ``z = (x(t2) - x(t1)) / sqrt(that)``
tests "each calibration state is what the model says" without ground truth. The probe takes
the streaming Localizer's calibration (:meth:`Localizer.calibration`) every ``--grid`` s of
odometry, compares each snapshot ``k`` with the snapshots 1, 2, 4, ... back, spends ``alpha``
over the snapshots as the NIS windows spend theirs (snapshot ``k`` in block ``b =
floor(log2 k)`` gets ``alpha 6 / (pi^2 (b + 1)^2) / 2^b``,
:func:`odofuse.status.monitors.window_band`) and splits that share over its comparisons and
states (Bonferroni, two-sided normal).
Printed per log: the largest ``z`` over its bound (above 1: the test would fire), the state
and the times. Logs are :func:`bench_status.make_case`'s (nominal seeds and the
``gyro_bias_step`` fault); the Localizer is the filterpy path (``compiled: off``), which
the compiled offline run equals.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import bench_status  # noqa: E402


def snapshots(log, cfg, estimator: str, grid: float):
    """``(taken, walks)``: ``taken`` the ``(t, Localizer.calibration())`` pairs every ``grid``
    s of odometry, ``walks`` each calibration state's random walk per sqrt(s)."""
    from odofuse.estimators import localizer as L
    from odofuse.estimators import run_estimator

    taken, walks = [], {}
    original = L.Localizer.add_odometry

    def add_odometry(self, t, u):
        out = original(self, t, u)
        if not taken or t >= taken[-1][0] + grid:
            taken.append((float(t), self.calibration()))
            if not walks:
                for m in self.models.values():
                    walks.update(m.calib_walk() if hasattr(m, "calib_walk") else {})
                odo = getattr(self.backend, "odo_cal", None)
                walks.update(odo.calib_walk() if odo is not None else {})
        return out

    opts = dataclasses.replace(cfg.estimator_options(estimator), compiled="off")
    options = {**(cfg.options or {}), estimator: opts}
    run_cfg = dataclasses.replace(cfg, estimator=estimator, options=options)
    L.Localizer.add_odometry = add_odometry
    try:
        run_estimator(estimator, log, run_cfg)
    finally:
        L.Localizer.add_odometry = original
    return taken, walks


def largest_ratio(taken, walks, alpha: float) -> tuple[float, str]:
    """The largest ``|z|`` over its bound among the comparisons, and what it compared."""
    from scipy.stats import norm

    from odofuse.status.monitors import window_band

    names = list(taken[0][1]) if taken else []
    worst = (0.0, "no calibration state")
    for k in range(2, len(taken) + 1 if names else 0):
        lags = [k - 2**i for i in range(k.bit_length()) if k - 2**i >= 1]
        share = window_band(k, 1, 1, alpha, 1)[2]  # the NIS windows' alpha spending
        bound = float(norm.isf(share / (2 * len(lags) * len(names))))
        tk, ck = taken[k - 1]
        for j in lags:
            tj, cj = taken[j - 1]
            for s in names:
                var = cj[s]["sigma"] ** 2 - ck[s]["sigma"] ** 2 + walks.get(s, 0.0) ** 2 * (tk - tj)
                if var <= 0.0:
                    continue
                z = abs(ck[s]["value"] - cj[s]["value"]) / math.sqrt(var)
                if z / bound > worst[0]:
                    worst = (z / bound, f"{s}, {tj:.0f}-{tk:.0f} s: z {z:.2f}, bound {bound:.2f}")
    return worst


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nominal", type=int, nargs="*", default=[1000, 1001, 1002, 1003, 1004])
    p.add_argument("--faulty", type=int, nargs="*", default=list(range(1000, 1020)))
    p.add_argument("--grid", type=float, default=5.0, help="seconds between snapshots")
    p.add_argument("--alpha", type=float, default=1e-3, help="false-alarm probability per run")
    p.add_argument("--estimator", default="ekf", choices=("ekf", "ukf"))
    a = p.parse_args(argv)
    from odofuse.log_defaults import apply_log_defaults

    over = {}
    for kind, seeds in (("nominal", a.nominal), ("gyro_bias_step", a.faulty)):
        for seed in seeds:
            log, cfg, desc = bench_status.make_case(seed, None if kind == "nominal" else kind)
            cfg, log = apply_log_defaults(cfg, log)
            ratio, what = largest_ratio(*snapshots(log, cfg, a.estimator, a.grid), a.alpha)
            over.setdefault(kind, []).append(ratio > 1.0)
            print(f"{kind} {seed} {desc}: largest z / bound {ratio:.2f} ({what})", flush=True)
    for kind, flags in over.items():
        print(f"{kind}: over the bound on {sum(flags)} of {len(flags)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
