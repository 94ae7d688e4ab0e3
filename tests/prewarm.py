"""Fill numba's on-disk cache with the compiled core's signatures before the suite starts.

On a clean clone the cache is empty. Before this, each xdist worker and each ``odofuse``
subprocess of the CLI tests that reached a kernel before another process had saved it
compiled that kernel itself: the same signatures compiled several times at once on two cores
(about 115 s of CPU on a clean clone; docs/speed.md, "Session 53"). ``tests/conftest.py`` runs
this module in the xdist controller before the workers start, when the cache is cold: two
processes, one per core (:data:`JOBS`), each running short seeded logs through every compiled
path of its share, so that every later process only loads machine code. Nothing is asserted
here; the tests check these paths. A job that fails costs only time: the tests compile what
it did not.

``python tests/prewarm.py JOB`` runs one job.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: The two halves of the compiled core, about equal in compile time: the EKF's event loop and
#: dead reckoning; the UKF's event loop and the particle filter.
JOBS = ("ekf", "ukf")


def cold() -> bool:
    """Whether numba's cache holds no machine code of an entry kernel of either job."""
    try:
        from odofuse.estimators import compiled

        k = compiled.load_kernels()
    except Exception:  # noqa: BLE001 - no numba: nothing to warm
        return False
    if k is None:
        return False
    kernels = (k.filter_offline, k.ekf_predict_step, k.ukf_predict_step, k.pf_predict)
    return any(compiled.cold(d) for d in kernels + (k.dr_linear, k.dr_generic))


def start() -> list[subprocess.Popen]:
    """Start one process per job of :data:`JOBS` (output discarded)."""
    # the tests' own odofuse (numba keys its cache by the kernels' file path)
    path = os.pathsep.join(p for p in (str(HERE.parent), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, "PYTHONPATH": path}
    return [
        subprocess.Popen(
            [sys.executable, str(Path(__file__)), job],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for job in JOBS
    ]


def _filters(name: str, compiled_module, make_backend) -> None:
    """The offline event loop with and without robust odometry (``slip``: its arrays or
    None, two signatures), and a live Localizer."""
    from compiled_checks import SCENARIO, SLIP_SCENARIO, live_from_config
    from graph_sim import excerpt, simulated_run

    for slip in (False, True):
        options = {"odometry_calibration": slip, "slip": slip, "compiled": "on"}
        log, cfg = simulated_run(SCENARIO, 3, name, options)
        compiled_module.run(excerpt(log, 5.0), cfg)
    log, cfg = simulated_run(SLIP_SCENARIO, 3, name, {"late_window": 0.5})
    live_from_config(excerpt(log, 5.0), cfg, make_backend, 0.3)


def _dead_reckoning() -> None:
    """A linear drive's and a non-linear drive's kernel."""
    import numpy as np

    from odofuse.config import RunConfig
    from odofuse.estimators.compiled.dead_reckoning import dead_reckon
    from odofuse.motion import motion_model_from_config

    robots = (
        ({"drive": "differential", "wheel_radius": 0.05, "track_width": 0.3}, {"k_r": 2e-4}),
        ({"drive": "ackermann", "wheel_radius": 0.3, "wheelbase": 2.5, "track_width": 1.5}, {}),
    )
    for robot, motion in robots:
        model = motion_model_from_config(RunConfig(log="x", robot=robot, motion=motion))
        U = np.full((50, len(model.drive.input_names)), 0.1)
        for with_cov in (True, False):
            dead_reckon(model, np.zeros(3), np.eye(3), U, with_cov=with_cov, mode="on")


def _particle() -> None:
    from compiled_checks import SCENARIO
    from graph_sim import excerpt, simulated_run

    from odofuse.estimators.particle import run

    options = {"particles": 50, "seed": 3, "compiled": "on", "odometry_calibration": True}
    log, cfg = simulated_run(SCENARIO, 7, "particle", options)
    run(excerpt(log, 5.0), cfg)


def main(job: str) -> int:
    sys.path.insert(0, str(HERE))
    if job == "ekf":
        from odofuse.estimators.compiled import ekf
        from odofuse.estimators.ekf import make_backend

        _filters("ekf", ekf, make_backend)
        _dead_reckoning()
    else:
        from odofuse.estimators.compiled import ukf
        from odofuse.estimators.ukf import make_backend

        _filters("ukf", ukf, make_backend)
        _particle()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
