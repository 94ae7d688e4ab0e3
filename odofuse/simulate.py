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

A log folder (shared spec section 1) is written by :func:`write_log`: ``wheels.csv`` (ticks
with rollover when an encoder is configured, else radians), the sensor files, ``map.csv``,
``groundtruth.csv``, plus ``config.yaml`` (a run config for ``odofuse run``, nominal geometry)
and ``scenario.yaml`` (the scenario, the seed and the true geometry).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from odofuse import se2
from odofuse.errors import ConfigError
from odofuse.io.log import SensorLog, Stream

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

PATH_KINDS = ("square", "figure_eight", "waypoints", "twists")

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
# Error and sensor specifications
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SystematicErrors:
    """Systematic odometry errors: the true geometry differs from the nominal one.

    Parameters
    ----------
    E_d : float
        Ratio of the true right to left wheel diameter (Borenstein & Feng 1996). The mean
        diameter is kept: ``D_L = 2/(E_d + 1) D_a``, ``D_R = 2/(1/E_d + 1) D_a``. Only for drives
        with ``left``/``right`` wheels.
    E_b : float
        True wheelbase over nominal (track width for differential/skid-steer drives; see
        :data:`WHEELBASE_KEYS` for the others).
    E_s : float
        Common scale error: every true wheel radius is ``E_s`` times the nominal one.
    """

    E_d: float = 1.0
    E_b: float = 1.0
    E_s: float = 1.0


@dataclass(frozen=True)
class WheelNoise:
    """Non-systematic wheel errors.

    Parameters
    ----------
    k : float
        Variance of each wheel's ground travel per metre rolled, m^2/m (Siegwart's ``k_r = k_l``).
    steer_sigma : float
        Standard deviation of the steering angle actually held during a step, rad.
    slip_bursts : tuple of (t_start, t_end, wheel, fraction)
        In ``[t_start, t_end)`` (s) input ``wheel`` (name) only moves the robot by
        ``1 - fraction`` of what its encoder counts.
    bumps : tuple of (t, wheel, extra_m)
        At the step containing ``t`` the encoder of ``wheel`` counts ``extra_m`` metres of
        rotation that did not move the robot (climbing over a bump).
    """

    k: float = 0.0
    steer_sigma: float = 0.0
    slip_bursts: tuple = ()
    bumps: tuple = ()


@dataclass(frozen=True)
class EncoderSpec:
    """Incremental encoders: ``ticks_per_rev`` ticks per wheel revolution, counter modulus."""

    ticks_per_rev: float
    rollover: int | None = None


@dataclass(frozen=True)
class GyroSpec:
    """Yaw-rate gyro: white noise ``sigma`` (rad/s), constant ``bias`` (rad/s), bias random walk
    ``bias_walk`` (rad/s per sqrt(s)); ``rate`` in Hz (``None``: every simulation step)."""

    sigma: float = 0.005
    bias: float = 0.0
    bias_walk: float = 0.0
    rate: float | None = None


@dataclass(frozen=True)
class GpsSpec:
    """Position fixes in the world frame: noise ``sigma`` (m, per axis) at ``rate`` Hz; with
    probability ``outlier_prob`` a fix gets an extra ``outlier_sigma`` (m) error; no fixes in
    the ``outages`` intervals ``((t0, t1), ...)`` (s)."""

    sigma: float = 1.0
    rate: float = 1.0
    outlier_prob: float = 0.0
    outlier_sigma: float = 20.0
    outages: tuple = ()


@dataclass(frozen=True)
class RangeSpec:
    """Ranges to every beacon within ``max_range`` (m) at ``rate`` Hz, noise ``sigma`` (m);
    outliers add ``outlier_sigma`` with probability ``outlier_prob``."""

    sigma: float = 0.1
    rate: float = 2.0
    max_range: float = math.inf
    outlier_prob: float = 0.0
    outlier_sigma: float = 5.0


@dataclass(frozen=True)
class LandmarkSpec:
    """Range (m) and bearing (rad, robot frame) to landmarks within ``max_range`` and inside the
    field of view ``fov`` (rad, centred on the heading) at ``rate`` Hz."""

    sigma_range: float = 0.1
    sigma_bearing: float = 0.02
    rate: float = 2.0
    max_range: float = math.inf
    fov: float = 2.0 * math.pi


@dataclass(frozen=True)
class CompassSpec:
    """Absolute heading (rad) with noise ``sigma`` (rad) at ``rate`` Hz."""

    sigma: float = 0.05
    rate: float = 1.0


@dataclass(frozen=True)
class Scenario:
    """Everything a simulation needs; together with ``seed`` it fixes the log.

    Parameters
    ----------
    drive : str
        Drive name (``odofuse.drives.DRIVES`` key).
    geometry : mapping
        Nominal drive geometry (the values the estimator is told), SI units.
    path : mapping
        Manoeuvre: ``{"kind": one of PATH_KINDS, ...}`` (see :func:`path_twists`).
    dt : float
        Simulation step, s.
    initial_pose : tuple of 3 floats
        True start pose ``[x, y, theta]`` (m, m, rad).
    systematic, wheel_noise : SystematicErrors, WheelNoise
    encoder : EncoderSpec or None
        When given, ``wheels.csv`` holds ticks instead of radians.
    gyro, gps, ranges, landmarks, compass : sensor specs or None
    beacons : ndarray (M, 3)
        ``id, x, y`` of beacons/landmarks (world frame, m).
    seed : int
    actual_geometry : mapping or None
        The true geometry, given explicitly; when set, ``systematic`` is ignored. Used to
        re-run a robot after its nominal geometry was calibrated.
    """

    drive: str = "differential"
    geometry: Mapping = field(default_factory=lambda: {"wheel_radius": 0.04, "track_width": 0.235})
    path: Mapping = field(default_factory=lambda: {"kind": "square"})
    dt: float = 0.02
    initial_pose: tuple = (0.0, 0.0, 0.0)
    systematic: SystematicErrors = SystematicErrors()
    wheel_noise: WheelNoise = WheelNoise()
    encoder: EncoderSpec | None = None
    gyro: GyroSpec | None = None
    gps: GpsSpec | None = None
    ranges: RangeSpec | None = None
    landmarks: LandmarkSpec | None = None
    compass: CompassSpec | None = None
    beacons: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    seed: int = 0
    actual_geometry: Mapping | None = None


@dataclass(frozen=True)
class Simulation:
    """The result of :func:`simulate`.

    Attributes
    ----------
    scenario : Scenario
    t : ndarray (N+1,)
        Step boundaries, s.
    truth : ndarray (N+1, 3)
        True poses (world frame), theta wrapped.
    twists_cmd : ndarray (N, 3)
        Commanded body twists per step ``[omega, v_x, v_y]``.
    u_meas : ndarray (N, n)
        What the robot's sensors read per step: wheel angle increments (rad, before
        quantisation) and steering angles (rad). Feed these to the nominal motion model.
    u_true : ndarray (N, n)
        The inputs that actually moved the robot through the true geometry.
    streams : dict[str, Stream]
        Sensor streams as written to the log (``wheels`` in ticks when an encoder is set).
    nominal_geometry, true_geometry : dict
    input_names : tuple of str
    """

    scenario: Scenario
    t: np.ndarray
    truth: np.ndarray
    twists_cmd: np.ndarray
    u_meas: np.ndarray
    u_true: np.ndarray
    streams: dict
    nominal_geometry: dict
    true_geometry: dict
    input_names: tuple


# --------------------------------------------------------------------------------------------
# Path generators: sequences of per-step body twists (Delta t = 1 per step)
# --------------------------------------------------------------------------------------------


def _segments(length: float, per_step: float) -> int:
    return max(1, int(math.ceil(abs(length) / per_step - 1e-9)))


def _straight(distance: float, v: float, dt: float) -> np.ndarray:
    n = _segments(distance, v * dt)
    return np.tile([0.0, distance / n, 0.0], (n, 1))


def _turn(angle: float, w: float, dt: float) -> np.ndarray:
    if abs(angle) < 1e-12:
        return np.empty((0, 3))
    n = _segments(angle, w * dt)
    return np.tile([angle / n, 0.0, 0.0], (n, 1))


def _arc(angle: float, radius: float, v: float, dt: float) -> np.ndarray:
    length = abs(angle) * radius
    n = _segments(length, v * dt)
    return np.tile([angle / n, length / n, 0.0], (n, 1))


def square_twists(
    side: float = 4.0,
    direction: str = "ccw",
    *,
    speed: float = 0.3,
    turn_rate: float = 0.8,
    dt: float = 0.02,
    laps: int = 1,
    corner_radius: float = 0.0,
) -> np.ndarray:
    """Body twists of a square path, UMBmark style.

    The robot starts at a corner heading along +x of its body frame, drives ``side`` metres,
    turns 90 degrees (left for ``"ccw"``, right for ``"cw"``), four times per lap, ending where
    it started with its initial heading. With ``corner_radius > 0`` the corners are arcs (for
    drives that cannot turn in place); the legs shorten so the square keeps its size.

    Parameters
    ----------
    side : float
        Side length L, m.
    direction : {"ccw", "cw"}
    speed : float
        Forward speed, m/s.
    turn_rate : float
        Turn rate in place, rad/s.
    dt : float
        Step, s.
    laps : int
    corner_radius : float
        m; 0 turns in place.

    Returns
    -------
    ndarray (N, 3)
        ``[omega, v_x, v_y]`` per step (rad, m, m).
    """
    if direction not in ("cw", "ccw"):
        raise ValueError(f"square direction must be 'cw' or 'ccw', got {direction!r}")
    if side <= 2 * corner_radius or speed <= 0 or turn_rate <= 0 or dt <= 0 or laps < 1:
        raise ValueError("square needs side > 2 corner_radius, positive speed, turn_rate, dt, laps")
    sgn = 1.0 if direction == "ccw" else -1.0
    leg = _straight(side - 2 * corner_radius, speed, dt)
    if corner_radius > 0:
        corner = _arc(sgn * math.pi / 2, corner_radius, speed, dt)
        lap = np.vstack([np.vstack([leg, corner]) for _ in range(4)])
        return np.vstack([lap] * laps)
    lap = np.vstack([np.vstack([leg, _turn(sgn * math.pi / 2, turn_rate, dt)]) for _ in range(4)])
    return np.vstack([lap] * laps)


def figure_eight_twists(
    radius: float = 2.0, *, speed: float = 0.3, dt: float = 0.02, laps: int = 1
) -> np.ndarray:
    """Body twists of a figure eight: a full left circle then a full right circle of ``radius``
    (m) at ``speed`` (m/s), repeated ``laps`` times; it returns to its start pose."""
    if radius <= 0 or speed <= 0 or dt <= 0 or laps < 1:
        raise ValueError("figure eight needs positive radius, speed, dt and laps")
    left = _arc(2 * math.pi, radius, speed, dt)
    right = _arc(-2 * math.pi, radius, speed, dt)
    return np.vstack([left, right] * laps)


def turn_drive_turn_twists(
    start, waypoints, *, speed: float = 0.3, turn_rate: float = 0.8, dt: float = 0.02
) -> np.ndarray:
    """Body twists of a waypoint tour driven by turn-drive-turn inverse kinematics.

    Politecnico slides (``003_73fced8ec7c15fe5.txt``, "Differential drive inverse kinematics"):
    1. turn in place to face the next position, 2. drive straight to it, 3. when the waypoint
    has a heading, turn in place to it.

    Parameters
    ----------
    start : array_like (3,)
        Start pose ``[x, y, theta]``.
    waypoints : array_like (K, 2) or (K, 3)
        Positions (m), optionally with the heading to end in (rad).

    Returns
    -------
    ndarray (N, 3)
    """
    from odofuse.drives import turn_drive_turn

    pose = np.asarray(start, dtype=float).copy()
    if isinstance(waypoints, np.ndarray):
        waypoints = np.atleast_2d(waypoints).tolist()
    wps = [np.asarray(w, dtype=float).reshape(-1) for w in waypoints]
    if not wps or any(w.size not in (2, 3) for w in wps):
        raise ValueError("waypoints must be a non-empty list of [x, y] or [x, y, theta]")
    parts = []
    for wp in wps:
        d = wp[:2] - pose[:2]
        # a waypoint without heading keeps the heading of its approach leg
        goal_theta = (
            wp[2] if wp.size == 3 else (math.atan2(d[1], d[0]) if np.hypot(*d) > 0 else pose[2])
        )
        goal = np.array([wp[0], wp[1], goal_theta])
        turn1, drive, turn2 = turn_drive_turn(pose, goal)
        parts += [_turn(turn1[0], turn_rate, dt)]
        if drive[1] > 0:
            parts.append(_straight(drive[1], speed, dt))
        parts.append(_turn(turn2[0], turn_rate, dt))
        pose = goal
    out = np.vstack([p for p in parts if len(p)] or [np.empty((0, 3))])
    if len(out) == 0:
        raise ValueError("waypoint tour does not move the robot")
    return out


def path_twists(path: Mapping, dt: float, start=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Dispatch a path description ``{"kind": ..., params}`` to its generator.

    Kinds: ``square`` (:func:`square_twists` keywords), ``figure_eight``
    (:func:`figure_eight_twists`), ``waypoints`` (``points: [[x, y(, theta)], ...]``,
    ``speed``, ``turn_rate``) and ``twists`` (``values: [[omega, v_x, v_y], ...]`` per step).
    """
    params = dict(path)
    kind = params.pop("kind", "square")
    try:
        if kind == "square":
            return square_twists(dt=dt, **params)
        if kind == "figure_eight":
            return figure_eight_twists(dt=dt, **params)
        if kind == "waypoints":
            points = params.pop("points")
            return turn_drive_turn_twists(start, points, dt=dt, **params)
        if kind == "twists":
            values = np.asarray(params.pop("values"), dtype=float)
            if params or values.ndim != 2 or values.shape[1] != 3:
                raise ValueError("twists path needs only 'values' of shape (N, 3)")
            return values
    except TypeError as exc:  # unknown keyword
        raise ValueError(f"path '{kind}': {exc}") from None
    raise ValueError(f"unknown path kind {kind!r}; use one of {', '.join(PATH_KINDS)}")


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
        g[key] = float(g[key]) * errors.E_s
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
    robot = {"drive": sc.drive, **{k: float(v) for k, v in sc.geometry.items()}}
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
    sensors: dict = {}
    if sc.gyro is not None:
        sensors["gyro"] = {"sigma": float(max(sc.gyro.sigma, 1e-6)), "calibrate": True}
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
        "nominal_geometry": {k: float(v) for k, v in sim.nominal_geometry.items()},
        "true_geometry": {k: float(v) for k, v in sim.true_geometry.items()},
        "systematic": {
            "E_d": float(sc.systematic.E_d),
            "E_b": float(sc.systematic.E_b),
            "E_s": float(sc.systematic.E_s),
        },
        "wheel_noise": {
            "k": float(sc.wheel_noise.k),
            "steer_sigma": float(sc.wheel_noise.steer_sigma),
            "slip_bursts": [list(map(_plain, b)) for b in sc.wheel_noise.slip_bursts],
            "bumps": [list(map(_plain, b)) for b in sc.wheel_noise.bumps],
        },
        "path": {k: _plain(v) for k, v in dict(sc.path).items()},
        "steps": int(len(sim.twists_cmd)),
    }


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
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

    from odofuse.io.csvlog import write_csv_log
    from odofuse.outputs import atomic_write_text

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


# --------------------------------------------------------------------------------------------
# Scenario files (configs/sim-*.yaml)
# --------------------------------------------------------------------------------------------

_TOP_KEYS = (
    "seed",
    "dt",
    "robot",
    "initial_pose",
    "path",
    "systematic",
    "nonsystematic",
    "sensors",
    "beacons",
)


def _block(d, key: str, source: str) -> dict:
    v = d.get(key) if isinstance(d, Mapping) else None
    if v is None:
        return {}
    if not isinstance(v, Mapping):
        raise ConfigError("must be a mapping", source, key)
    return dict(v)


def _spec(cls, block: Mapping, source: str, key: str):
    names = set(cls.__dataclass_fields__)
    for k in block:
        if k not in names:
            raise ConfigError(
                f"unknown key (known: {', '.join(sorted(names))})", source, f"{key}.{k}"
            )
    kwargs = {}
    for k, v in block.items():
        default = cls.__dataclass_fields__[k].default
        if isinstance(default, tuple):
            if not isinstance(v, (list, tuple)):
                raise ConfigError("must be a list", source, f"{key}.{k}")
            kwargs[k] = tuple(tuple(x) if isinstance(x, (list, tuple)) else x for x in v)
        elif v is None:
            kwargs[k] = None
        else:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"must be a finite number, got {v!r}", source, f"{key}.{k}")
            problem = _value_problem(k, float(v))
            if problem:
                raise ConfigError(f"{problem}, got {v!r}", source, f"{key}.{k}")
            kwargs[k] = float(v)
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(str(exc), source, key) from None


def _value_problem(name: str, v: float) -> str | None:
    """Range check of a scalar scenario value by its field name (None when fine)."""
    if name.startswith("E_") or name == "rate":
        return None if v > 0 else "must be positive"
    if name.endswith("prob"):
        return None if 0.0 <= v <= 1.0 else "must be a probability in [0, 1]"
    if "sigma" in name or name in ("k", "bias_walk", "max_range", "fov"):
        return None if v >= 0 else "must not be negative"
    return None


def scenario_from_dict(d: Mapping, source: str = "<scenario>") -> Scenario:
    """Build a :class:`Scenario` from the YAML form of ``configs/sim-*.yaml``.

    Raises
    ------
    odofuse.errors.ConfigError
        Unknown keys, wrong types or bad values, naming the key and ``source``.
    """
    if not isinstance(d, Mapping):
        raise ConfigError("a scenario must be a mapping", source)
    for k in d:
        if k not in _TOP_KEYS:
            raise ConfigError(f"unknown key (known: {', '.join(_TOP_KEYS)})", source, str(k))
    robot = _block(d, "robot", source)
    drive = robot.pop("drive", "differential")
    enc = robot.pop("encoder", None)
    encoder = None
    if enc is not None:
        if not isinstance(enc, Mapping) or "ticks_per_rev" not in enc:
            raise ConfigError("needs ticks_per_rev", source, "robot.encoder")
        rollover = enc.get("rollover")
        encoder = EncoderSpec(
            float(enc["ticks_per_rev"]), None if rollover is None else int(rollover)
        )
    for k, v in robot.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
            raise ConfigError(
                f"geometry must be a positive number, got {v!r}", source, f"robot.{k}"
            )
    path = _block(d, "path", source) or {"kind": "square"}
    if path.get("kind", "square") not in PATH_KINDS:
        raise ConfigError(
            f"unknown path kind {path.get('kind')!r} (known: {', '.join(PATH_KINDS)})",
            source,
            "path.kind",
        )
    systematic = _spec(SystematicErrors, _block(d, "systematic", source), source, "systematic")
    wheel_noise = _spec(WheelNoise, _block(d, "nonsystematic", source), source, "nonsystematic")
    sensors = _block(d, "sensors", source)
    classes = {
        "gyro": GyroSpec,
        "gps": GpsSpec,
        "ranges": RangeSpec,
        "landmarks": LandmarkSpec,
        "compass": CompassSpec,
    }
    specs = {}
    for k, v in sensors.items():
        if k not in classes:
            raise ConfigError(
                f"unknown sensor (known: {', '.join(classes)})", source, f"sensors.{k}"
            )
        specs[k] = _spec(classes[k], v or {}, source, f"sensors.{k}")
    seed = d.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ConfigError(f"must be an integer, got {seed!r}", source, "seed")
    rng = np.random.default_rng(seed)
    beacons = _beacons(d.get("beacons"), rng, source)
    dt = d.get("dt", 0.02)
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not dt > 0:
        raise ConfigError(f"must be a positive number, got {dt!r}", source, "dt")
    pose0 = d.get("initial_pose", [0.0, 0.0, 0.0])
    if not isinstance(pose0, (list, tuple)) or len(pose0) != 3:
        raise ConfigError("must be [x, y, theta]", source, "initial_pose")
    return Scenario(
        drive=str(drive),
        geometry=robot,
        path=path,
        dt=float(dt),
        initial_pose=tuple(float(v) for v in pose0),
        systematic=systematic,
        wheel_noise=wheel_noise,
        encoder=encoder,
        beacons=beacons,
        seed=seed,
        **specs,
    )


def _beacons(spec, rng, source: str) -> np.ndarray:
    if spec is None:
        return np.empty((0, 3))
    if isinstance(spec, Mapping):
        count = int(spec.get("count", 6))
        lo = np.asarray(spec.get("min", [-10.0, -10.0]), dtype=float)
        hi = np.asarray(spec.get("max", [10.0, 10.0]), dtype=float)
        xy = rng.uniform(lo, hi, (count, 2))
        return np.column_stack([np.arange(1, count + 1), xy])
    arr = np.asarray(spec, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ConfigError("must be a list of [id, x, y] or {count, min, max}", source, "beacons")
    return arr


def load_scenario(path) -> Scenario:
    """Read a scenario YAML file (``configs/sim-*.yaml``); errors name the key and the file."""
    import yaml

    path = Path(path)
    try:
        d = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"cannot read: {exc.strerror}", str(path)) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"malformed YAML: {exc}", str(path)) from None
    return scenario_from_dict(d, str(path))
