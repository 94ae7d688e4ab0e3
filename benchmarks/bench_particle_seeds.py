"""The particle filter's Monte Carlo error against its own covariance, without ground truth.

Run from any directory: ``python benchmarks/bench_particle_seeds.py [--first S] [--seeds N]
[--variants NAME ...]``.

A particle filter's estimate is the posterior mean plus a Monte Carlo error; its covariance
covers the first only. Two runs of the filter on the same log with different ``seed`` differ
by the Monte Carlo errors alone, so their position disagreement in the sum of their
covariances, ``d^T (P_0 + P_1)^-1 d`` averaged over the poses, is small for a filter whose
covariance can be honest (about 0.1 when the Monte Carlo variance is a tenth of the
posterior's) and of order 1 or more when the cloud has collapsed onto seed-dependent values.
No ground truth is read, so this is how ``options.particle`` defaults are chosen.

The logs are ``bench_status.py``'s nominal logs (:func:`bench_status.make_case`) on seeds the
status benchmark does not use (default 5000-5089; wheels-only logs are skipped: with no
update there is nothing to resample). Each variant overrides ``options.particle`` of the
user's config. Printed per sensor set and variant: the median, 90th percentile and largest
disagreement and the number of logs above 0.5 and above 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import bench_status as bs  # noqa: E402

#: Variant name -> ``options.particle`` overrides.
VARIANTS = {
    "roughening=0.1": {"roughening": 0.1},  # the default until session 33
    "roughening=0.2": {"roughening": 0.2},
    "roughening=0.3": {"roughening": 0.3},  # the default since
    "bandwidth_scale=1.5": {"roughening": 0.1, "bandwidth_scale": 1.5},
    "bandwidth_scale=2": {"roughening": 0.1, "bandwidth_scale": 2.0},
    "roughening=0.2,bandwidth_scale=1.5": {"roughening": 0.2, "bandwidth_scale": 1.5},
}


def disagreement(cfg, log, overrides: dict, seeds=(0, 1)) -> float:
    """Mean over poses (the first excluded: every seed starts at the prior) of the position
    disagreement of two particle runs in the sum of their covariances."""
    from odofuse.rundir import estimate

    runs = []
    for seed in seeds:
        options = dict(cfg.options)
        options["particle"] = {**options.get("particle", {}), **overrides, "seed": seed}
        run_cfg = dataclasses.replace(cfg, estimator="particle", options=options)
        result, _ = estimate(run_cfg, log, None)
        runs.append(result.trajectory)
    d = runs[0].poses[1:, :2] - runs[1].poses[1:, :2]
    S = runs[0].covariances[1:, :2, :2] + runs[1].covariances[1:, :2, :2]
    return float(np.einsum("ni,nij,nj->n", d, np.linalg.inv(S), d).mean())


def main(argv=None) -> int:
    from odofuse.log_defaults import apply_log_defaults

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--first", type=int, default=5000)
    p.add_argument("--seeds", type=int, default=90)
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    a = p.parse_args(argv)
    rows = []
    for seed in range(a.first, a.first + a.seeds):
        if bs.nominal_combination(seed)[1] == "wheels":
            continue
        log, cfg, what = bs.make_case(seed)
        cfg, log = apply_log_defaults(cfg, log)
        row = {v: disagreement(cfg, log, VARIANTS[v]) for v in a.variants}
        rows.append((what.split("/")[1], row))
        print(f"  seed {seed} {what}: " + " ".join(f"{v} {x:.3f}" for v, x in row.items()))
        sys.stdout.flush()
    for sensors in sorted({s for s, _ in rows}) + ["all"]:
        sel = [r for s, r in rows if sensors in ("all", s)]
        print(f"{sensors}: {len(sel)} logs")
        for v in a.variants:
            x = np.array([r[v] for r in sel])
            print(
                f"  {v:22s} median {np.median(x):.3f}  p90 {np.percentile(x, 90):.3f}  "
                f"max {x.max():.2f}  > 0.5: {(x > 0.5).sum()}  > 1: {(x > 1).sum()}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
