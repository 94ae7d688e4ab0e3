"""A GPS multipath burst in a log's last readings: what each estimator's status says.

The status benchmark's GPS multipath fault (``bench_status.FAULTS``) lies in the middle of
its logs. Here the burst ends the log: every other fix of the last 15 is moved 8 m east (8
fixes, never ``reject_run`` in a row), and the GPS stream ends 1 s early, so that its last
readings fall between two of the rejection count's strided evaluations (94 fixes, the last
4 past the stride's last evaluation, for the filters' gate and the smoother's residuals).
On the 1 m GPS logs (the even seeds) the gate rejects all 8; on the 2 m ones (odd seeds)
about half. docs/trust.md, "The rejection count's last window".

    python benchmarks/bench_end_burst.py --first 18100 --seeds 10 --estimators ekf ukf smoother
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_status as bs  # noqa: E402


def end_burst(log, fault=None, seed: int = 0):
    """``log`` with its GPS ending 1 s early and every other fix of its last 15 moved 8 m
    east (the signature of :func:`bench_status.inject`, whose place it takes)."""
    st = log.streams["gps"]
    keep = st.t <= st.t[-1] - 1.0 + 1e-9
    t, v = st.t[keep].copy(), st.values[keep].copy()
    burst = np.zeros(t.size, bool)
    burst[-15::2] = True
    v[burst, st.columns.index("x")] += 8.0
    return bs._with_stream(log, bs.Stream(st.name, st.source, t, st.columns, v))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--first", type=int, default=18100)
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--estimators", nargs="*", default=["ekf", "ukf", "smoother"])
    args = p.parse_args(argv)
    bs.inject = end_burst  # make_case's injection: the burst at the end instead
    degraded = dict.fromkeys(args.estimators, 0)
    for seed in range(args.first, args.first + args.seeds):
        log, cfg, what = bs.make_case(seed, "gps_multipath")
        out = bs.run_log(log, cfg, args.estimators, model_bounds=False)
        for est, row in out.items():
            degraded[est] += row[0] == "degraded"
            print(f"{seed} {what} {est}: {row[0]} {row[3][:90]}", flush=True)
    print("degraded: " + ", ".join(f"{e} {n} of {args.seeds}" for e, n in degraded.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
