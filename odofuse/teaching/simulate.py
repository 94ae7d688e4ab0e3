"""Simulated robots: true trajectory, wheel readings with systematic and random errors, sensors.

The simulator separates what the robot *does* from what its odometry *believes*, the split that
every odometry error discussion starts from (``002_88fc37db58155723.txt``, "Sources of error",
after Borenstein):

1. A path generator turns a manoeuvre (square clockwise or counter-clockwise, figure eight,
   a waypoint tour driven turn-drive-turn as in the Politecnico slides
   ``003_73fced8ec7c15fe5.txt``) into one commanded body twist ``[omega, v_x, v_y]`` per step.
2. The robot's controller converts each twist into wheel inputs with the **nominal** drive
   geometry (``drive.inverse``): its own odometry therefore reproduces the commanded path.
3. The wheels really move the robot through the **true** geometry: unequal wheel radii ``E_d``
   (Borenstein's ratio of right to left diameter), a wheelbase error ``E_b`` (actual over
   nominal), a common scale error ``E_s``; plus non-systematic errors, i.e. random travel noise
   per wheel with variance ``k |ds_i|`` (Siegwart & Nourbakhsh ch. 5, ``004_f4547100a083f338.txt``),
   slip bursts (a wheel's ground travel shrinks while its encoder keeps counting) and bumps (the
   encoder counts extra rotation the floor never saw).
4. The true pose advances by the exact twist exponential (Modern Robotics 13.35,
   ``000_96a7e9c96987202e.txt``); sensors sample it: gyro (noise, bias, bias random walk), GPS
   (noise, outliers, outages), compass, beacon ranges and landmark range/bearing.

Everything random comes from one ``numpy.random.default_rng(seed)``, drawn in a fixed order,
so a scenario and a seed reproduce a log bit for bit.

This module owns the simulator (:func:`simulate`, steps 2-4) and the true geometry
(:func:`true_geometry`), and is the public face of the simulation: it re-exports the scenario
dataclasses and file loading (:mod:`odofuse.teaching.scenario`), the path generators (step 1,
:mod:`odofuse.teaching.paths`) and the log writing (:mod:`odofuse.teaching.simlog`,
:func:`write_log`), so ``from odofuse.teaching.simulate import ...`` reaches all of it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from odofuse import se2
from odofuse.io.log import Stream
from odofuse.teaching.paths import (
    figure_eight_twists,
    path_twists,
    square_twists,
    turn_drive_turn_twists,
)
from odofuse.teaching.scenario import (
    PATH_KINDS,
    CompassSpec,
    EncoderSpec,
    GpsSpec,
    GyroSpec,
    LandmarkSpec,
    RangeSpec,
    Scenario,
    Simulation,
    SystematicErrors,
    WheelNoise,
    load_scenario,
    scenario_from_dict,
)
from odofuse.teaching.simlog import plain, to_sensor_log, write_log

__all__ = [
    "SystematicErrors",
    "WheelNoise",
    "EncoderSpec",
    "GyroSpec",
    "GpsSpec",
    "RangeSpec",
    "LandmarkSpec",
    "CompassSpec",
    "Scenario",
    "Simulation",
    "square_twists",
    "figure_eight_twists",
    "turn_drive_turn_twists",
    "path_twists",
    "true_geometry",
    "simulate",
    "encoder_ticks",
    "to_sensor_log",
    "write_log",
    "load_scenario",
    "scenario_from_dict",
    "PATH_KINDS",
]
#: Geometry key that the wheelbase error ``E_b`` scales, per drive (the lateral distance that
#: converts wheel travel into rotation).
WHEELBASE_KEYS: dict[str, tuple[str, ...]] = {
    "differential": ("track_width",),
    "skid_steer": ("track_width",),
    "omni3": ("wheel_distance",),
    "mecanum4": ("half_width", "half_length"),
}
#: Keys tried, in order, for drives not in :data:`WHEELBASE_KEYS`.
_WHEELBASE_FALLBACK = ("track_width", "wheelbase", "wheel_distance", "length", "d")


# --------------------------------------------------------------------------------------------
# Systematic errors -> true geometry
# --------------------------------------------------------------------------------------------


def true_geometry(drive: str, geometry: Mapping, errors: SystematicErrors) -> dict:
    """The robot's true geometry given its nominal geometry and systematic errors.

    ``E_s`` scales every wheel radius; ``E_d`` splits the left/right radii keeping their mean
    (Borenstein & Feng: ``D_L = 2/(E_d+1) D_a``, ``D_R = 2/(1/E_d+1) D_a``); ``E_b`` scales the
    wheelbase key(s) of :data:`WHEELBASE_KEYS`.

    Raises
    ------
    ValueError
        ``E_d != 1`` for a drive without left/right wheel radii, or ``E_b != 1`` for a drive
        whose wheelbase key is unknown.
    """
    g = dict(geometry)
    for key in [k for k in g if k.startswith("wheel_radius")]:
        g[key] = plain(np.asarray(g[key], dtype=float) * errors.E_s)  # one or per wheel
    if errors.E_d != 1.0:
        if drive not in ("differential", "skid_steer"):
            raise ValueError(
                f"E_d (unequal wheel diameters) applies to left/right wheels; "
                f"drive '{drive}' has none"
            )
        r = float(g.get("wheel_radius", 0.0))
        r_l = float(g.pop("wheel_radius_left", r))
        r_r = float(g.pop("wheel_radius_right", r))
        g["wheel_radius_left"] = r_l * 2.0 / (errors.E_d + 1.0)
        g["wheel_radius_right"] = r_r * 2.0 / (1.0 / errors.E_d + 1.0)
    if errors.E_b != 1.0:
        keys = WHEELBASE_KEYS.get(drive) or tuple(k for k in _WHEELBASE_FALLBACK if k in g)[:1]
        keys = tuple(k for k in keys if k in g)
        if not keys:
            raise ValueError(
                f"E_b: no wheelbase key known for drive '{drive}' (geometry keys: {', '.join(g)})"
            )
        for key in keys:
            g[key] = float(g[key]) * errors.E_b
    return g


# --------------------------------------------------------------------------------------------
# Simulation
# --------------------------------------------------------------------------------------------


def _make_drive(name: str, geometry: Mapping):
    from odofuse.drives import make_drive

    return make_drive(name, **dict(geometry))


def _every(rate: float | None, dt: float, what: str) -> int:
    if rate is None:
        return 1
    if rate <= 0:
        raise ValueError(f"{what}.rate must be positive, got {rate}")
    return max(1, int(round(1.0 / (rate * dt))))


def encoder_ticks(angles, spec: EncoderSpec) -> np.ndarray:
    """Cumulative wheel angles (rad) -> encoder counter readings.

    Quantisation floors to whole ticks (a counter counts completed edges); with a rollover the
    counter is reduced modulo ``rollover`` into ``[0, rollover)``.

    Parameters
    ----------
    angles : array_like (...)
        Cumulative wheel angles, rad.

    Returns
    -------
    ndarray (...) of float holding integers
    """
    ticks = np.floor(np.asarray(angles, dtype=float) * spec.ticks_per_rev / (2.0 * math.pi))
    if spec.rollover:
        ticks = np.mod(ticks, float(spec.rollover))
    return ticks


def _window_mean(x: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of consecutive windows of ``m`` samples and the index of each window's last one."""
    n = (len(x) // m) * m
    return x[:n].reshape(-1, m).mean(axis=1), np.arange(m - 1, n, m)


def simulate(scenario: Scenario, seed: int | None = None) -> Simulation:
    """Run a scenario.

    Parameters
    ----------
    scenario : Scenario
    seed : int, optional
        Overrides ``scenario.seed``.

    Returns
    -------
    Simulation
    """
    sc = scenario if seed is None else replace(scenario, seed=int(seed))
    rng = np.random.default_rng(sc.seed)
    dt = float(sc.dt)
    if not dt > 0:
        raise ValueError(f"dt must be positive, got {sc.dt}")
    nominal = _make_drive(sc.drive, sc.geometry)
    if sc.actual_geometry is not None:
        true_geom = dict(sc.actual_geometry)
    else:
        true_geom = true_geometry(sc.drive, sc.geometry, sc.systematic)
    true_drive = _make_drive(sc.drive, true_geom)
    names = tuple(nominal.input_names)
    scale = np.asarray(nominal.travel_scale(), dtype=float)
    wheel = scale > 0  # inputs that roll (wheels, steering increments): cumulative, noisy
    kinds = tuple(getattr(nominal, "input_kinds", ("wheel" if w else "steer" for w in wheel)))
    encoded = np.array([k == "wheel" for k in kinds])  # counted by encoders (ticks)
    pose0 = np.asarray(sc.initial_pose, dtype=float)

    twists = path_twists(sc.path, dt, pose0)
    N = len(twists)
    t = np.arange(N + 1) * dt
    u_cmd = np.asarray(nominal.inverse(twists), dtype=float).reshape(N, len(names))
    if not np.all(np.isfinite(u_cmd)):
        raise ValueError(
            f"drive '{sc.drive}' cannot follow path '{dict(sc.path).get('kind')}' "
            "(inverse kinematics not finite; try corner_radius > 0)"
        )

    # Non-systematic errors: random travel noise, slip bursts, bumps.
    noise = sc.wheel_noise
    u_true = u_cmd.copy()
    if noise.k > 0:
        travel = np.abs(u_cmd[:, wheel] * scale[wheel])
        u_true[:, wheel] += (
            rng.normal(0.0, 1.0, travel.shape) * np.sqrt(noise.k * travel) / scale[wheel]
        )
    if noise.steer_sigma > 0 and (~wheel).any():
        u_true[:, ~wheel] += rng.normal(0.0, noise.steer_sigma, (N, int((~wheel).sum())))
    t_mid = t[:-1] + 0.5 * dt
    for t0, t1, name, fraction in noise.slip_bursts:
        j = _input_index(names, name, wheel)
        inside = (t_mid >= t0) & (t_mid < t1)
        u_true[inside, j] *= 1.0 - float(fraction)
    u_meas = u_cmd.copy()
    for tb, name, extra in noise.bumps:
        j = _input_index(names, name, wheel)
        k = min(N - 1, max(0, int(tb // dt)))
        u_meas[k, j] += float(extra) / scale[j]

    # True motion: exact exponential of the true twist of each step.
    tw_true = np.asarray(true_drive.twist(u_true), dtype=float).reshape(N, 3)
    # Head-to-tail composition of all steps at once: headings are a running sum, each step's
    # displacement is rotated by the heading at its start.
    delta = se2.exp(tw_true)
    heading = pose0[2] + np.concatenate([[0.0], np.cumsum(delta[:, 2])])
    c, s_ = np.cos(heading[:-1]), np.sin(heading[:-1])
    disp = np.column_stack([c * delta[:, 0] - s_ * delta[:, 1], s_ * delta[:, 0] + c * delta[:, 1]])
    truth = np.empty((N + 1, 3))
    truth[0, :2] = pose0[:2]
    truth[1:, :2] = pose0[:2] + np.cumsum(disp, axis=0)
    truth[:, 2] = se2.wrap(heading)

    streams: dict[str, Stream] = {}
    # Wheels: cumulative angles of wheel inputs, steering angle held during the step.
    cum = np.vstack([np.zeros((1, len(names))), np.cumsum(u_meas, axis=0)])
    values = cum.copy()
    if (~wheel).any():
        steer = u_meas[:, ~wheel]
        values[:, ~wheel] = np.vstack([steer[:1], steer])
    if sc.encoder is not None:
        values[:, encoded] = encoder_ticks(cum[:, encoded], sc.encoder)
    if sc.drive == "increments":
        # odometry.csv: the increments since the previous row (the form of Plaza's DR stream)
        streams["odometry"] = Stream("odometry", "simulation", t[1:], names, u_meas)
    elif set(kinds) == {"velocity"}:
        # cmd_vel.csv: row k's velocity holds until row k+1 (the last row repeats it)
        vel = np.vstack([u_meas, u_meas[-1:]]) / dt
        streams["cmd_vel"] = Stream("cmd_vel", "simulation", t, names, vel)
    else:
        streams["wheels"] = Stream("wheels", "simulation", t, names, values)

    if sc.gyro is not None:
        g = sc.gyro
        rate_true = tw_true[:, 0] / dt
        walk = (
            np.cumsum(rng.normal(0.0, g.bias_walk * math.sqrt(dt), N)) if g.bias_walk > 0 else 0.0
        )
        raw = rate_true + g.bias + walk
        m = _every(g.rate, dt, "gyro")
        mean, last = _window_mean(raw, m)
        wz = mean + rng.normal(0.0, g.sigma, mean.shape)
        streams["gyro"] = Stream("gyro", "simulation", t[last + 1], ("wz",), wz[:, None])

    if sc.gps is not None:
        s = sc.gps
        idx = np.arange(0, N + 1, _every(s.rate, dt, "gps"))
        xy = truth[idx, :2] + rng.normal(0.0, s.sigma, (len(idx), 2))
        outlier = rng.random(len(idx)) < s.outlier_prob
        xy += outlier[:, None] * rng.normal(0.0, s.outlier_sigma, (len(idx), 2))
        keep = np.ones(len(idx), dtype=bool)
        for a, b in s.outages:
            keep &= ~((t[idx] >= a) & (t[idx] < b))
        streams["gps"] = Stream("gps", "simulation", t[idx][keep], ("x", "y"), xy[keep])

    if sc.compass is not None:
        c = sc.compass
        idx = np.arange(0, N + 1, _every(c.rate, dt, "compass"))
        heading = se2.wrap(truth[idx, 2] + rng.normal(0.0, c.sigma, len(idx)))
        streams["compass"] = Stream("compass", "simulation", t[idx], ("heading",), heading[:, None])

    beacons = np.asarray(sc.beacons, dtype=float).reshape(-1, 3)
    if sc.ranges is not None and len(beacons):
        r = sc.ranges
        idx = np.arange(0, N + 1, _every(r.rate, dt, "ranges"))
        d = np.hypot(
            truth[idx, None, 0] - beacons[None, :, 1], truth[idx, None, 1] - beacons[None, :, 2]
        )
        z = d + rng.normal(0.0, r.sigma, d.shape)
        z += (rng.random(d.shape) < r.outlier_prob) * np.abs(
            rng.normal(0.0, r.outlier_sigma, d.shape)
        )
        ii, jj = np.nonzero(d <= r.max_range)
        rows = np.column_stack([beacons[jj, 0], np.maximum(z[ii, jj], 0.0)])
        streams["ranges"] = Stream("ranges", "simulation", t[idx][ii], ("id", "range"), rows)

    if sc.landmarks is not None and len(beacons):
        lm = sc.landmarks
        idx = np.arange(0, N + 1, _every(lm.rate, dt, "landmarks"))
        dx = beacons[None, :, 1] - truth[idx, None, 0]
        dy = beacons[None, :, 2] - truth[idx, None, 1]
        d = np.hypot(dx, dy)
        bearing = se2.wrap(np.arctan2(dy, dx) - truth[idx, None, 2])
        zr = d + rng.normal(0.0, lm.sigma_range, d.shape)
        zb = se2.wrap(bearing + rng.normal(0.0, lm.sigma_bearing, d.shape))
        ii, jj = np.nonzero((d <= lm.max_range) & (np.abs(bearing) <= 0.5 * lm.fov))
        rows = np.column_stack([beacons[jj, 0], np.maximum(zr[ii, jj], 0.0), zb[ii, jj]])
        streams["landmarks"] = Stream(
            "landmarks", "simulation", t[idx][ii], ("id", "range", "bearing"), rows
        )

    return Simulation(
        sc, t, truth, twists, u_meas, u_true, streams, dict(sc.geometry), true_geom, names
    )


def _input_index(names: tuple, name, wheel: np.ndarray) -> int:
    if isinstance(name, (int, np.integer)) and 0 <= int(name) < len(names):
        j = int(name)
    elif name in names:
        j = names.index(name)
    else:
        raise ValueError(f"unknown wheel {name!r}; this drive's inputs are {names}")
    if not wheel[j]:
        raise ValueError(f"input {names[j]!r} is a steering angle, not a wheel")
    return j
