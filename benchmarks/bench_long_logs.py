"""Status, position RMSE and NEES of the EKF and the smoother on longer status-benchmark logs.

Run from any directory: ``python benchmarks/bench_long_logs.py [--laps L] [--seeds N]
[--first S]``. The logs of ``bench_geometry_advice.py`` (``bench_status.make_case`` with the
path driven ``--laps`` times: the 3 % wheel radius and track faults, the real robot, and the
nominal differential gyro-GPS logs), each run as ``bench_status.run_log`` runs it (second
opinion included, no model bounds). One line per log: each estimator's status, position RMSE
(m) and mean position NEES over its Sokal bound, the smoother's first warning and the EKF's.
docs/trust.md, "The geometry advice on longer logs", has the 4- and 16-lap tables (16 laps:
about 10 min here).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import bench_geometry_advice as bg  # noqa: E402
import bench_status as bs  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--laps", type=int, default=16, help="laps of each log's path (default 16)")
    ap.add_argument("--seeds", type=int, default=10, help="logs per kind (default 10)")
    ap.add_argument("--first", type=int, default=16000, help="first seed (default 16000)")
    args = ap.parse_args(argv)
    bs.LAPS = args.laps
    for kind, seed in bg.cases(args.seeds, args.first):
        log, cfg, what = bs.make_case(seed, kind)
        out = bs.run_log(log, cfg, ["ekf", "smoother"], model_bounds=False)
        cells = [f"{e} {r[0]} {r[4]:.3f} {r[1]:.2f}/{r[2]:.2f}" for e, r in out.items()]
        warn = [out["smoother"][3][:60], out["ekf"][3][:70]]
        print(args.laps, kind or "nominal", seed, what, "|", " | ".join(cells + warn), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
