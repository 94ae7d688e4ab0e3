"""Dead reckoning's position NEES with and without a declared odometry-calibration prior.

Run from any directory (about a minute; on a shared machine use ``nice``)::

    nice -n 10 python benchmarks/bench_dead_reckoning_calibration.py [--seeds 20]

``options.dead_reckoning.odometry_calibration`` (issues 10/11) adds the unobserved prior of the
odometry's systematic errors to dead reckoning's covariance. Printed, per log: position RMSE
(unchanged by construction) and mean position NEES (issue 11's band: 1 to 4) of the plain run
and of the run with the prior declared (the graph's default sigmas unless a row says otherwise):

* Plaza1 and Plaza2 with ``odofuse/default_configs/plaza1-dead_reckoning.yaml`` (only ``log:``
  changed);
* the simulated robots of ``tests/test_tune.py`` (seed 1, no systematic error; mecanum4 has no
  odometry-calibration parametrisation, so declaring it is a config error there);
* the UMBmark squares (``configs/sim-umbmark-{cw,ccw}.yaml``: E_d 1.002, E_b 1.01);
* differential and skid-steer robots whose E_d, E_b are drawn from the declared prior
  (``--seeds`` of them, mean and median NEES): the situation the prior describes.

Ground truth is used only to score.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from odofuse.config import config_from_dict, load_config  # noqa: E402
from odofuse.errors import ConfigError  # noqa: E402
from odofuse.estimators import run_estimator  # noqa: E402
from odofuse.evaluation import metrics  # noqa: E402
from odofuse.io.loader import load_log, load_log_for  # noqa: E402
from odofuse.teaching.scenario import load_scenario, scenario_from_dict  # noqa: E402
from odofuse.teaching.simlog import run_config, to_sensor_log, write_log  # noqa: E402
from odofuse.teaching.simulate import simulate  # noqa: E402
from tests.test_tune import ROBOTS, _sim  # noqa: E402 - the tests' robots

PRIOR = 0.05  # the graph's default prior sigma of E_d and E_b


def _pair(cfg, log, sigma=None) -> tuple:
    """((rmse, nees) plain, (rmse, nees) or a reason, with the prior declared)."""
    plain = metrics(run_estimator("dead_reckoning", log, cfg), log)
    opts = {"odometry_calibration": True}
    if sigma is not None:
        opts["odometry_calibration_sigma"] = list(sigma)
    try:
        cal = dataclasses.replace(cfg, options={**cfg.options, "dead_reckoning": opts})
        m = metrics(run_estimator("dead_reckoning", log, cal), log)
    except ConfigError as exc:
        return (plain["ate_rmse_m"], plain["nees_position_mean"]), str(exc)[:40]
    return (plain["ate_rmse_m"], plain["nees_position_mean"]), (
        m["ate_rmse_m"],
        m["nees_position_mean"],
    )


def _row(name, a, b) -> None:
    right = b if isinstance(b, str) else f"{b[0]:9.3f} m  NEES {b[1]:9.3f}"
    print(f"{name:34s} {a[0]:9.3f} m  NEES {a[1]:9.3f}   |  {right}", flush=True)


def _sim_config(sim):
    return config_from_dict(run_config(sim, "dead_reckoning"), "<bench>")


def drawn(drive: str, seeds: int) -> None:
    """Robots whose systematic errors come from the declared prior (one draw per seed)."""
    rng = np.random.default_rng(7)
    robot = {"drive": drive, "wheel_radius": 0.04, "track_width": 0.235}
    a, b = [], []
    for seed in range(seeds):
        e_d, e_b = 1.0 + PRIOR * rng.normal(size=2)
        sc = {
            "seed": seed,
            "dt": 0.2,
            "robot": robot,
            "path": {"kind": "figure_eight", "radius": 3.0, "speed": 0.4, "laps": 2},
            "nonsystematic": {"k": 5e-4},
            "systematic": {"E_d": float(e_d), "E_b": float(e_b)},
        }
        sim = simulate(scenario_from_dict(sc, "<bench>"))
        p, c = _pair(_sim_config(sim), to_sensor_log(sim))
        a.append(p[1])
        b.append(c[1])
    print(
        f"{drive + f' x{seeds}, E_d, E_b ~ prior':34s} NEES mean {np.mean(a):9.2f} "
        f"median {np.median(a):7.2f}   |  NEES mean {np.mean(b):7.2f} median {np.median(b):7.2f}",
        flush=True,
    )


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=20)
    args = p.parse_args(argv)
    print(f"{'log':34s} {'plain':>26s}   |  prior declared")
    base = load_config(ROOT / "odofuse" / "default_configs" / "plaza1-dead_reckoning.yaml")
    for name in ("builtin:plaza1", "builtin:plaza2"):
        _row(name, *_pair(dataclasses.replace(base, log=name), load_log(name)))
    for name, (robot, sensors, _) in sorted(ROBOTS.items()):
        sim = _sim(robot, sensors, seed=1)
        _row(f"{name} (seed 1)", *_pair(_sim_config(sim), to_sensor_log(sim)))
    for direction in ("cw", "ccw"):  # encoder ticks: through the log folder, as a user would
        sim = simulate(load_scenario(ROOT / "configs" / f"sim-umbmark-{direction}.yaml"))
        with tempfile.TemporaryDirectory() as tmp:
            write_log(sim, tmp, "dead_reckoning")
            cfg = load_config(Path(tmp) / "config.yaml")
            _row(f"umbmark-{direction}", *_pair(cfg, load_log_for(cfg)))
    for drive in ("differential", "skid_steer"):
        drawn(drive, args.seeds)


if __name__ == "__main__":
    main()
