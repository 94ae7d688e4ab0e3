"""``odofuse tune`` against known truth (issue 11): simulated robots and Plaza1.

Run from any directory (it takes minutes; on a shared machine use ``nice``)::

    nice -n 10 python benchmarks/bench_tune.py [--seed 1] [--plaza-seconds 600] [--no-plaza]

1. The three simulated robots of ``tests/test_tune.py`` (differential + GPS, mecanum4 +
   compass, differential + ranges; seeded, true wheel noise known): tuning starts 3x (odometry
   ``k``) and 2x (sensor sigma) off the truth; printed: learned / true per key (target within
   30 %), the inverse-Hessian 1-sigma factor, the tuned config's RMSE against the RMSE with the
   true noise (the best a hand tuner could reach), runs and seconds.
2. Plaza1: ``configs/plaza1-ekf.yaml`` tuned on its own log (keys ``motion.k[0]``,
   ``motion.k_theta_ds``, ``sensors.ranges.sigma``; ground truth never read), then scored with
   ground truth on Plaza1 and Plaza2 (only ``log:`` changed) against the hand-tuned references
   ``configs/handtuned-plaza{1,2}-ekf.yaml`` (target: within 1.1x).

Ground truth is used only to score, after tuning.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from odofuse import tune as T  # noqa: E402
from odofuse.config import config_from_dict, load_config  # noqa: E402
from odofuse.estimators import run_estimator  # noqa: E402
from odofuse.evaluation import metrics  # noqa: E402
from odofuse.io.loader import load_log  # noqa: E402
from odofuse.teaching.simlog import to_sensor_log  # noqa: E402
from tests.test_tune import ROBOTS, _rmse, _sim, _true_raw  # noqa: E402 - the tests' robots

PLAZA_KEYS = ("motion.k[0]", "motion.k_theta_ds", "sensors.ranges.sigma")
QUIET = {"progress": lambda line: None}


def simulated(seed: int) -> list[dict]:
    rows = []
    for name, (robot, sensors, keys) in sorted(ROBOTS.items()):
        sim = _sim(robot, sensors, seed=seed)
        log = to_sensor_log(sim)
        raw = _true_raw(sim)
        truth = [T.get_value(raw, k) for k in keys]
        start = T.set_values(raw, keys, [v * f for v, f in zip(truth, (3.0, 2.0), strict=True)])
        res = T.tune(config_from_dict(start, "<bench>"), start, log, keys, **QUIET)
        rows.append(
            {
                "name": name,
                "keys": keys,
                "ratio": [v / t for v, t in zip(res.values, truth, strict=True)],
                "sigma": res.log_sigma,
                "rmse": (_rmse(res.raw, log), _rmse(raw, log)),
                "runs": res.evaluations,
                "seconds": res.seconds,
                "stopped": res.stopped,
            }
        )
        print(f"  {name}: done in {res.seconds:.0f} s", flush=True)
    return rows


def _score(cfg, name: str, log) -> tuple[float, float]:
    m = metrics(run_estimator("ekf", log, dataclasses.replace(cfg, log=name)), log)
    return m["ate_rmse_m"], m["nees_position_mean"]


def plaza(max_seconds: float) -> dict:
    res, out = T.tune_config(
        ROOT / "configs" / "plaza1-ekf.yaml",
        Path("/tmp") / "bench_tune-plaza1-ekf.yaml",
        PLAZA_KEYS,
        max_seconds=max_seconds,
        **QUIET,
    )
    tuned = load_config(out)
    rows = {}
    for n in ("plaza1", "plaza2"):
        name = f"builtin:{n}"
        log = load_log(name)
        ref = load_config(ROOT / "configs" / f"handtuned-{n}-ekf.yaml")
        rows[n] = (_score(tuned, name, log), _score(ref, name, log))
    return {"res": res, "rows": rows}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--plaza-seconds", type=float, default=600.0, help="tune's time bound")
    p.add_argument("--no-plaza", action="store_true")
    a = p.parse_args(argv)
    clock = time.perf_counter()
    print(f"simulated robots (seed {a.seed}):", flush=True)
    sims = simulated(a.seed)
    pl = None if a.no_plaza else plaza(a.plaza_seconds)
    print("\nsimulated robots: learned / true (1-sigma factor), target within 30 %")
    print(f"{'robot':22s} {'key':22s} {'ratio':>7s} {'1-sigma':>8s}  tuned / true-noise RMSE")
    for r in sims:
        for i, k in enumerate(r["keys"]):
            s = r["sigma"][i]
            band = "-" if s is None else f"x/{math.exp(s):.3f}"
            ok = "ok" if abs(r["ratio"][i] - 1.0) < 0.3 else "MISSED"
            tail = (
                f"  {r['rmse'][0]:.3f} / {r['rmse'][1]:.3f} m  ({r['runs']} runs, "
                f"{r['seconds']:.0f} s, {r['stopped']})"
                if i == 0
                else ""
            )
            print(f"{r['name']:22s} {k:22s} {r['ratio'][i]:7.3f} {band:>8s} {ok:6s}{tail}")
    if pl is not None:
        res = pl["res"]
        print(f"\nPlaza1 tune ({res.evaluations} runs, {res.seconds:.0f} s, {res.stopped}):")
        print("\n".join("  " + line for line in T.report_lines(res)[2:]))
        head = f"{'log':8s} {'tuned RMSE (NEES)':>20s} {'hand-tuned RMSE (NEES)':>24s}"
        print(f"{head} {'ratio':>6s}")
        for n, ((r, e), (r0, e0)) in pl["rows"].items():
            print(f"{n:8s} {r:10.3f} m ({e:5.2f}) {r0:13.3f} m ({e0:5.2f}) {r / r0:6.2f}")
    print(f"\ntotal {time.perf_counter() - clock:.0f} s")


if __name__ == "__main__":
    main()
