"""Simulated runs as logs: an in-memory :class:`~odofuse.io.log.SensorLog` or a log folder.

:func:`write_log` writes the folder of the shared spec section 1: ``wheels.csv`` (ticks with
rollover when an encoder is configured, else radians), the sensor files, ``map.csv``,
``groundtruth.csv``, plus ``config.yaml`` (a run config for ``odofuse run``, nominal geometry,
:func:`run_config`) and ``scenario.yaml`` (the scenario, the seed and the true geometry). Every
file is written atomically.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from odofuse.drives import make_drive
from odofuse.io.log import SensorLog, Stream
from odofuse.teaching.scenario import Simulation

# --------------------------------------------------------------------------------------------
# Log folder
# --------------------------------------------------------------------------------------------


def to_sensor_log(sim: Simulation, source: str = "simulation") -> SensorLog:
    """The simulation as a :class:`SensorLog` (wheels as in the log file: ticks or radians)."""
    gt = Stream("groundtruth", source, sim.t, ("x", "y", "theta"), sim.truth)
    beacons = np.asarray(sim.scenario.beacons, dtype=float).reshape(-1, 3)
    landmarks = {int(b[0]): b[1:].copy() for b in beacons}
    return SensorLog(
        source,
        dict(sim.streams),
        landmarks,
        gt,
        {},
        np.asarray(sim.scenario.initial_pose, dtype=float),
    )


def run_config(sim: Simulation, estimator: str = "ekf") -> dict:
    """A run config (shared spec section 2) for the written log, with the *nominal* geometry."""
    sc = sim.scenario
    robot = {"drive": sc.drive, **{k: plain(v) for k, v in sc.geometry.items()}}
    if sc.encoder is not None:
        robot["encoder"] = {"ticks_per_rev": float(sc.encoder.ticks_per_rev)}
        if sc.encoder.rollover:
            robot["encoder"]["rollover"] = int(sc.encoder.rollover)
    k = max(float(sc.wheel_noise.k), 1e-6)
    motion: dict = {"integrator": "exact"}
    if sim.input_names[:2] == ("left", "right"):
        motion.update(k_r=k, k_l=k)
    else:
        motion["k"] = k
    if hasattr(make_drive(sc.drive, **sc.geometry), "heading_input"):
        # The simulator draws each input's noise alone (var(dtheta) = k |dtheta|); the default
        # k_theta_ds (a two-wheel robot's heading variance per metre) would add k |ds| more
        motion["k_theta_ds"] = 0.0
    sensors: dict = {}
    if sc.gyro is not None:
        sensors["gyro"] = {"sigma": float(max(sc.gyro.sigma, 1e-6)), "calibrate": True}
        if sc.gyro.bias_walk > 0:  # the simulated walk, as the sigmas are the simulated ones
            sensors["gyro"]["bias_walk"] = float(sc.gyro.bias_walk)
    if sc.gps is not None:
        sensors["gps"] = {"sigma": float(sc.gps.sigma), "gate": 0.999}
    if sc.compass is not None:
        sensors["compass"] = {"sigma": float(sc.compass.sigma)}
    if sc.ranges is not None and len(np.asarray(sc.beacons)):
        sensors["ranges"] = {"sigma": float(sc.ranges.sigma), "gate": 0.999}
    if sc.landmarks is not None and len(np.asarray(sc.beacons)):
        sensors["landmarks"] = {
            "sigma_range": float(sc.landmarks.sigma_range),
            "sigma_bearing": float(sc.landmarks.sigma_bearing),
        }
    return {
        "log": ".",
        "robot": robot,
        "motion": motion,
        "estimator": estimator,
        "initial": {"pose": [float(v) for v in sc.initial_pose], "sigma": [0.01, 0.01, 0.01]},
        "sensors": sensors,
        "output": "out",
    }


def _scenario_record(sim: Simulation) -> dict:
    sc = sim.scenario
    return {
        "seed": int(sc.seed),
        "dt": float(sc.dt),
        "drive": sc.drive,
        "nominal_geometry": {k: plain(v) for k, v in sim.nominal_geometry.items()},
        "true_geometry": {k: plain(v) for k, v in sim.true_geometry.items()},
        "systematic": {
            "E_d": float(sc.systematic.E_d),
            "E_b": float(sc.systematic.E_b),
            "E_s": float(sc.systematic.E_s),
        },
        "wheel_noise": {
            "k": float(sc.wheel_noise.k),
            "steer_sigma": float(sc.wheel_noise.steer_sigma),
            "slip_bursts": [list(map(plain, b)) for b in sc.wheel_noise.slip_bursts],
            "bumps": [list(map(plain, b)) for b in sc.wheel_noise.bumps],
        },
        "path": {k: plain(v) for k, v in dict(sc.path).items()},
        "steps": int(len(sim.twists_cmd)),
    }


def plain(v):
    """``v`` as plain Python (floats, ints, nested lists) for YAML/JSON."""
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    return v


def write_log(sim: Simulation, folder, estimator: str = "ekf") -> list[Path]:
    """Write the simulation as a log folder (shared spec section 1).

    Writes every stream, ``groundtruth.csv``, ``map.csv`` (when there are beacons),
    ``config.yaml`` (a run config with the nominal geometry; its ``log`` is ``.``) and
    ``scenario.yaml`` (seed, nominal and true geometry, errors). Files are written atomically.

    Returns
    -------
    list of Path
    """
    import yaml

    from odofuse.io.atomic import atomic_write_text
    from odofuse.io.csvlog import write_csv_log

    folder = Path(folder)
    written = write_csv_log(to_sensor_log(sim, str(folder)), folder)
    if isinstance(written, tuple):  # (paths, repairs-made) in newer io versions
        written = written[0]
    atomic_write_text(
        folder / "config.yaml", yaml.safe_dump(run_config(sim, estimator), sort_keys=False)
    )
    atomic_write_text(
        folder / "scenario.yaml", yaml.safe_dump(_scenario_record(sim), sort_keys=False)
    )
    return [*written, folder / "config.yaml", folder / "scenario.yaml"]
