"""iSAM2 SLAM's status on simulated landmark logs: false alarms and a slip it must see.

Run from any directory: ``python benchmarks/bench_slam_status.py [--seeds N] [--first S]
[--fault-seeds M] [--estimators isam2 smoother]``.

iSAM2 with ``slam: true`` tests each re-sighting of a landmark already in its graph against
its own prediction (``odofuse.estimators.graph.innovations``, the filters' NIS checks at their
defaults, as on the localisation path). This benchmark measures what that buys, on logs of
:mod:`bench_status`'s kind (the same robot, error draws per seed and noise levels; the
config a user writes: geometry, the wheel error model, each sensor's sigma, ``slam: true``):

* **nominal**: the differential robot (the geometry its config states: a SLAM run does not
  calibrate the odometry by default; ``--real-wheels`` gives it :mod:`bench_status`'s
  systematic errors) on a 2-lap figure eight with a range-bearing sensor
  (2 Hz, 10 m) seeing :data:`LANDMARKS` (unknown to the run), with a gyro on odd seeds;
  noise level ``(seed // 2) % 2``. Printed: the fraction ``degraded`` against ``alpha_run``
  with its binomial 99 % bound.
* **slip_burst**: the same logs without a gyro, the left wheel slipping 40 % over 30-33 s
  (:mod:`bench_status`'s fault): only the landmarks can see it.
* For every run that says ``ok``: its position NEES against the chi-square 99.9 % bound of
  its run (:func:`bench_status.nees_bound`), and against the bound its solution's joint
  covariance implies (:func:`bench_status.model_nees_bound`). The map frame is the run's
  own, anchored by the first pose's prior (the config's initial pose, the simulator's
  start), as its covariance is; ground truth only scores.

Serial on purpose (the machine's two cores are shared).
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_status as bs  # noqa: E402

ESTIMATORS = ("isam2", "smoother")
#: Landmarks (id, x, y; m) around the figure eight (radius 3 m lobes about x = +-3 m).
LANDMARKS = [
    [1, 0.0, 6.0],
    [2, 0.0, -6.0],
    [3, 8.0, 0.0],
    [4, -8.0, 0.0],
    [5, 5.0, 5.0],
    [6, -5.0, -5.0],
    [7, 5.0, -5.0],
    [8, -5.0, 5.0],
]
#: Range-bearing noise per level of ``bench_status.NOISE``: sigma range (m), bearing (rad).
LANDMARK_NOISE = ((0.05, 0.01), (0.2, 0.03))


def scenario(seed: int, fault: str | None, real_wheels: bool = False) -> tuple[dict, dict]:
    """``(scenario, user config)`` of one log; ``real_wheels``: the wheels keep
    :mod:`bench_status`'s systematic errors (``E_d``, ``E_b``, sigma 0.2 %), which a SLAM run
    does not calibrate by default (``odometry_calibration: auto`` is off with ``slam``)."""
    level = (seed // 2) % 2
    noise = bs.NOISE[level]
    sc = bs.scenario_dict(seed, "differential", "gyro_gps", noise, fault)
    if not real_wheels:  # the geometry the config states, as bench_status's wheels-only logs
        sc["systematic"] = {}
    sr, sb = LANDMARK_NOISE[level]
    sensors = {"landmarks": {"sigma_range": sr, "sigma_bearing": sb, "rate": 2.0}}
    sensors["landmarks"]["max_range"] = 10.0
    if seed % 2 and fault is None:
        sensors["gyro"] = sc["sensors"]["gyro"]
    sc = {**sc, "sensors": sensors, "beacons": LANDMARKS, "path": {**sc["path"], "laps": 2}}
    cfg = bs.user_config(sc | {"sensors": {}}, noise)
    cfg["sensors"] = {"landmarks": {"sigma_range": sr, "sigma_bearing": sb}}
    if "gyro" in sensors:
        cfg["sensors"]["gyro"] = {"sigma": float(sensors["gyro"]["sigma"])}
    cfg["options"] = {e: {"slam": True} for e in ESTIMATORS}
    # the simulator starts exactly there: the prior of the first pose fixes the map's frame,
    # and says so (a sigma of 0.01 rad alone would be 8 cm at the far landmarks, an error the
    # run never has: every NEES would read low)
    cfg["initial"]["sigma"] = [1e-3, 1e-3, 1e-4]
    return sc, cfg


def write_case(seed: int, fault: str | None, folder, real_wheels: bool = False) -> Path:
    """:func:`scenario` simulated and written as ``odofuse simulate`` writes a log folder, with
    the user's config: its path (the written map is not given to the run)."""
    import yaml

    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import write_log
    from odofuse.teaching.simulate import simulate

    sc, user = scenario(seed, fault, real_wheels)
    write_log(simulate(scenario_from_dict(sc, f"seed {seed}")), folder)
    cfg_path = Path(folder) / "config.yaml"
    cfg_path.write_text(yaml.safe_dump(user, sort_keys=False))
    return cfg_path


def make_case(seed: int, fault: str | None = None, real_wheels: bool = False):
    """``(log, config, description)``: :func:`write_case` read back as ``odofuse run`` reads
    it."""
    from odofuse.config import load_config
    from odofuse.io.loader import load_log_for

    with tempfile.TemporaryDirectory(prefix="odofuse-slam-status-") as folder:
        cfg = load_config(write_case(seed, fault, folder, real_wheels))
        log = load_log_for(cfg)
    sensors = "+".join(sorted(n for n in cfg.sensors))
    return log, cfg, f"{sensors}/noise{(seed // 2) % 2}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=100, help="nominal seeds (default 100)")
    p.add_argument("--first", type=int, default=2000, help="first seed (default 2000)")
    p.add_argument("--fault-seeds", type=int, default=20, help="slip seeds (default 20)")
    p.add_argument("--estimators", nargs="*", default=list(ESTIMATORS), choices=ESTIMATORS)
    p.add_argument(
        "--real-wheels",
        action="store_true",
        help="wheels with bench_status's systematic errors, which SLAM does not calibrate",
    )
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    table = bs.measure(
        range(args.first, args.first + args.seeds),
        args.estimators,
        ["slip_burst"],
        range(args.first, args.first + args.fault_seeds),
        case=functools.partial(make_case, real_wheels=args.real_wheels),
    )
    print(
        f"\n{time.perf_counter() - t0:.0f} s; alpha_run {bs.ALPHA_RUN}, bounds at "
        f"{bs.BOUND_CONFIDENCE:.0%} (binomial), NEES at {bs.NEES_PROBABILITY} (chi-square, n_eff)"
    )
    for line in bs.summary(table, args.estimators):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
