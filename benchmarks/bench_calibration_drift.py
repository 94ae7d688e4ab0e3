"""The calibration drift check's margins (issue 25; docs/trust.md, "The calibration drift
check"): per log, the largest ``|z|`` over its bound of the EKF's or UKF's drift check
(:mod:`odofuse.status.drift`; above 1 the check fires), on nominal logs and on the gyro bias
step.

Run from any directory: ``python benchmarks/bench_calibration_drift.py [--nominal S ...]
[--faulty S ...] [--estimator ekf]``.

Logs are :func:`bench_status.make_case`'s (nominal seeds and the ``gyro_bias_step`` fault),
run with the config's options (``drift_alpha`` 1e-3, ``drift_grid`` 5 s by default); the
ratio is the run's ``extra.calibration_drift.ratio`` (``metrics.json``). ``bench_status.py``
gives the status those runs end with; this gives how far each log is from the bound.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import bench_status  # noqa: E402


def drift_ratio(seed: int, fault: str | None, estimator: str) -> tuple[float, str]:
    """``(ratio, description)`` of one log: the drift check's largest ``|z|`` over its bound
    (0 without calibration states), the state and span in the finding when it fired."""
    from odofuse.estimators import run_estimator
    from odofuse.log_defaults import apply_log_defaults

    log, cfg, desc = bench_status.make_case(seed, fault)
    cfg, log = apply_log_defaults(cfg, log)
    res = run_estimator(estimator, log, dataclasses.replace(cfg, estimator=estimator))
    ratio = (res.extra.get("calibration_drift") or {}).get("ratio", 0.0)
    fired = [f.line() for f in res.findings if f.check == "calibration_drift"]
    return float(ratio), f"{desc}" + (f": {fired[0]}" if fired else "")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nominal", type=int, nargs="*", default=[1000, 1001, 1002, 1003, 1004])
    p.add_argument("--faulty", type=int, nargs="*", default=list(range(1000, 1020)))
    p.add_argument("--estimator", default="ekf", choices=("ekf", "ukf"))
    a = p.parse_args(argv)
    over: dict[str, list[float]] = {}
    for kind, seeds in (("nominal", a.nominal), ("gyro_bias_step", a.faulty)):
        for seed in seeds:
            ratio, what = drift_ratio(seed, None if kind == "nominal" else kind, a.estimator)
            over.setdefault(kind, []).append(ratio)
            print(f"{kind} {seed}: z / bound {ratio:.2f} ({what})", flush=True)
    for kind, ratios in over.items():
        n = sum(r > 1.0 for r in ratios)
        print(f"{kind}: over the bound on {n} of {len(ratios)} (largest {max(ratios):.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
