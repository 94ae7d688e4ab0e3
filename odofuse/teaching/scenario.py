"""Scenarios of the simulator: what is simulated, as frozen dataclasses, and their YAML files.

Owns the error specifications (:class:`SystematicErrors` ``E_d``, ``E_b``, ``E_s``;
:class:`WheelNoise` ``k |ds|``, slip bursts, bumps), the sensor specifications (encoder, gyro,
GPS, compass, beacon ranges, landmarks), :class:`Scenario` (drive, nominal geometry, path,
errors, sensors, seed), :class:`Simulation` (its result) and the reading of scenario files
``configs/sim-*.yaml`` (:func:`load_scenario`, :func:`scenario_from_dict`), whose errors name
the key and the file. The simulator itself is :mod:`odofuse.teaching.simulate`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from odofuse.errors import ConfigError

PATH_KINDS = ("square", "figure_eight", "waypoints", "twists")

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
        :data:`odofuse.teaching.simulate.WHEELBASE_KEYS` for the others).
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
        if isinstance(v, list | tuple) or (k == "holonomic" and isinstance(v, bool)):
            continue  # modules, base_frame_offset...: checked by the drive class
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
