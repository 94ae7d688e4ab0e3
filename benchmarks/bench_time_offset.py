"""The time-stamp test's statistic on nominal and late-stamped logs (``odofuse.status.latency``).

Run from any directory: ``python benchmarks/bench_time_offset.py [--seeds N] [--first S]
[--fault range_time_shift]``.

The batch smoother of each log of ``benchmarks/bench_status.py`` (nominal seeds ``S`` to
``S + N - 1``, or its fault logs with ``--fault``), run as ``odofuse run`` runs it; per fused
absolute stream it prints the test's ``z`` in the smoother's own system (``method: smoother
system``), the share of the offset's information its states ``absorbed``, and the offset
``tau_s``; then, over all streams, the mean and standard deviation of ``z`` (under the model
``z`` is standard normal; below 1 where robust weights and variance components make it
conservative), its largest ``|z|`` and how many exceed the bound. Asserts nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))


def main(argv=None) -> int:
    import bench_status as bs

    from odofuse.log_defaults import apply_log_defaults
    from odofuse.rundir import estimate

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=100)
    p.add_argument("--first", type=int, default=1000)
    p.add_argument("--fault", choices=sorted(bs.FAULTS), default=None)
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    zs, over, bound = [], [], None
    for seed in range(args.first, args.first + args.seeds):
        log, cfg, what = bs.make_case(seed, args.fault)
        cfg, log = apply_log_defaults(cfg, log)
        result, _ = estimate(dataclasses.replace(cfg, estimator="smoother"), log)
        block = (result.extra or {}).get("time_offset") or {}
        for stream, st in block.items():
            bound = st["bound_z"]
            zs.append(st["z"])
            if abs(st["z"]) > bound:
                over.append((seed, stream))
            print(
                f"{seed} {what} {stream}: z {st['z']:+.2f} ({st['method']}), absorbed "
                f"{st.get('absorbed', float('nan')):.2f}, tau {st['tau_s']:+.3f} s",
                flush=True,
            )
    z = np.asarray(zs)
    kind = args.fault or "nominal"
    last = args.first + args.seeds - 1
    print(f"\n{kind} seeds {args.first}-{last}: {time.perf_counter() - t0:.0f} s")
    if z.size:
        print(
            f"{z.size} tests: mean z {z.mean():+.3f}, sd {z.std():.3f}, largest |z| "
            f"{np.abs(z).max():.2f}; beyond +-{bound:.2f}: {len(over)} {over}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
