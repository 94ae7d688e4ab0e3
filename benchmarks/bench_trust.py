"""Issue 10's scenario set: every estimator either holds or says it is degraded.

Run from any directory: ``python benchmarks/bench_trust.py [--only NAME ...] [--estimators ...]
[--laps N]``. Prints, per scenario and estimator, the position RMSE (m), the position NEES
(expected 2), the status the run reported, and the verdict of
:func:`odofuse.teaching.trust_scenarios.judge`: ``holds`` (RMSE within 2x of the batch
smoother's and position NEES below 10), ``degraded`` (it said so) or ``SILENT`` (a silent
failure: neither).
The last line counts the silent failures (target: zero). Each degraded run's first warning is
printed under the table.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from odofuse.teaching import trust_scenarios as ts  # noqa: E402

ESTIMATORS = ("smoother", "dead_reckoning", "ekf", "ukf", "particle")


def scenarios(names, laps):
    """Yield ``(name, loader)`` with ``loader(estimator) -> (log, config)``."""
    for name in names:
        if name == "figure_eight":
            pair = ts.figure_eight()
            yield name, lambda _e, p=pair: p
        elif name == "plaza2":
            yield name, ts.plaza2
        else:
            pair = ts.simulated(name, laps)
            yield name, lambda _e, p=pair: p


def _f(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3g}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    names = ["figure_eight", *ts.SIMULATED, "plaza2"]
    p.add_argument("--only", nargs="*", default=names, help="scenarios to run")
    p.add_argument("--estimators", nargs="*", default=list(ESTIMATORS))
    p.add_argument("--laps", type=int, default=None, help="shorten simulated scenarios")
    args = p.parse_args(argv)
    rows, notes, silent = [], [], 0
    print(f"{'scenario':18} {'estimator':15} {'RMSE [m]':>9} {'NEES_pos':>9} status    verdict")
    for name, load in scenarios(args.only, args.laps):
        ref = None
        for est in args.estimators:
            log, cfg = load(est)
            try:
                m = ts.run(log, cfg, est)
            except Exception as exc:  # noqa: BLE001 - a crash is reported as such
                print(f"{name:18} {est:15} crashed: {exc}")
                silent += 1
                continue
            if est == "smoother":
                ref = m.get("ate_rmse_m")
            # The smoother is the RMSE reference; it is itself judged on its NEES alone.
            verdict = ts.judge(m, ref if est != "smoother" else math.inf)
            silent += verdict == "SILENT"
            rmse, nees = m.get("ate_rmse_m"), m.get("nees_position_mean")
            print(f"{name:18} {est:15} {_f(rmse):>9} {_f(nees):>9} {m['status']:9} {verdict}")
            sys.stdout.flush()
            rows.append((name, est, m))
            if m["warnings"]:
                notes.append(f"{name}/{est}: {m['warnings'][0]}")
    print(f"silent failures: {silent}")
    for line in notes:
        print("  " + line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
