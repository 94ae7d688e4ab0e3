"""Plausibility of a loaded log: readings that parse but cannot be what the config says.

The CSV parser (:mod:`odofuse.io.csvlog`) makes sure every cell is a finite number in order;
this module, run on the loaded arrays by :func:`odofuse.io.loader.load_log_for`, checks that
the numbers can be physical for this robot and config. Each check ends in one of

* an :class:`~odofuse.errors.InputError` naming the file, the row (as loaded: header = row 1,
  so the data row ``i`` is row ``i + 2`` when no repair reordered the file) and the column,
  when the run would otherwise be garbage (a step faster than the robot can go, times in
  nanoseconds, a gyro in degrees per second, lat/lon swapped);
* a :class:`~odofuse.status.findings.Finding` in ``log.findings`` (a ``warnings`` line of
  ``metrics.json``; ``degrades=True`` makes the run ``degraded``) when the data may be right
  but the estimate across it cannot be trusted (a wheels gap in which the counter may have
  wrapped more than once, GPS fixes far from anything local).

Checks (thresholds a priori, from the config and the data's own sampling, never from ground
truth). They judge measured times only: a stream the loader stamped itself
(``SensorLog.invented_times``: a pose graph's ``t = pose id``) enters no check that divides
by a time step or compares time scales (``speed``, ``time_units``, ``gps_jumps``,
``gyro_units``):

``speed``
    odometry / wheel / cmd_vel steps whose speed ``|v| = |(vx, vy)| / dt`` exceeds
    ``log.max_speed`` (m/s) or whose yaw rate ``|omega| / dt`` exceeds ``log.max_yaw_rate``
    (rad/s): an error. Typical causes, named in the message: encoder ticks read as radians
    (no ``robot.encoder`` block), a wrong ``encoder.rollover``, a counter reset, a corrupt row.
``time_units``
    a stream whose times exceed 1e11 (seconds since 1970 are ~1.7e9; ms, us and ns are
    1e3, 1e6, 1e9 times more), or whose times are >= 500 times those of the odometry and do
    not overlap them: an error naming the likely unit.
``counter_gap``
    a ``wheels.csv`` gap in which the wheel, at the fastest rate seen outside gaps, could
    turn more than half the counter range: the rollover unwrapping across it is ambiguous (a
    degrading finding).
``gps_swapped`` / ``gps_far`` / ``gps_jumps``
    lat/lon that match the datum only when swapped (error; the ranges [-90, 90] and
    [-180, 180] are the CSV loader's); local ``x, y`` fixes more than 100 km from the start
    pose, e.g. UTM coordinates without an origin (degrading finding); consecutive fixes
    implying a speed above ``log.max_speed`` (counted, non-degrading: the gate handles them).
``gyro_units``
    a gyro whose yaw rate is 45-70 times the wheels' (57.3 = degrees per radian): an error.
``wheel_scale``
    a gyro whose yaw rate is over :data:`WHEEL_SCALE` (skid steer: :data:`SKID_WHEEL_SCALE`)
    times the wheels' or under its inverse
    (outside the degrees band): the wheel increments do not fit the configured units (wheels
    logged in metres where radians are expected, a wrong ``robot.encoder.ticks_per_rev``,
    ``robot.wheel_radius`` or ``robot.track_width``): an error naming those keys.

A stream mostly rejected by its gate, or mostly dropped as late, is reported by the run
itself (:func:`odofuse.status.findings.rejection_findings`, the Localizer's ``dropped`` finding).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from odofuse.errors import InputError
from odofuse.status.findings import Finding

#: Defaults of ``log.max_speed`` (m/s) and ``log.max_yaw_rate`` (rad/s): generous for any
#: wheeled mobile robot (108 km/h; two turns a second), far below what a corrupt row gives.
MAX_SPEED = 30.0
MAX_YAW_RATE = 4.0 * math.pi
#: Times above this (s) are not seconds (1e11 s is 3,000 years after 1970).
MAX_SECONDS = 1e11
#: Two streams' times this many times apart (and not overlapping) use different units.
UNIT_RATIO = 500.0
#: Local GPS fixes farther than this (m) from the start pose are not local.
FAR_GPS = 1e5
DEG_PER_RAD = 180.0 / math.pi
#: Gyro / wheel yaw-rate ratio beyond which (or below whose inverse) the wheels' units are
#: wrong: slip and a few % of geometry error stay far inside a factor 2; a skid-steer robot's
#: wheels overstate its turns by about 2x, so it gets :data:`SKID_WHEEL_SCALE`.
WHEEL_SCALE = 2.0
SKID_WHEEL_SCALE = 4.0
ODOMETRY_STREAMS = ("wheels", "odometry", "cmd_vel")


def check_log(log, config, max_speed: float = MAX_SPEED, max_yaw_rate: float = MAX_YAW_RATE):
    """Run every check on ``log`` for ``config``; returns the log with its findings added.

    Parameters
    ----------
    log : SensorLog
        As loaded (SI units, repairs done).
    config : RunConfig
        ``robot`` (drive, geometry, encoder), ``sensors`` (gps datum) and ``initial``.
    max_speed : float
        Fastest plausible speed, m/s.
    max_yaw_rate : float
        Fastest plausible yaw rate, rad/s.

    Raises
    ------
    InputError
        For readings that cannot be right (see the module docstring).
    """
    findings: list[Finding] = []
    invented = set(getattr(log, "invented_times", ()) or ())
    _time_units(log, invented)
    drive = _drive(config)
    odo = next((s for s in ODOMETRY_STREAMS if log.has(s)), None)
    rates = None
    if drive is not None and odo is not None and odo not in invented:
        rates = _step_rates(log.streams[odo], drive, odo)
        if rates is not None:
            _speed(log.streams[odo], rates, max_speed, max_yaw_rate, config)
    if odo == "wheels":
        _wheel_columns(log.streams["wheels"], drive)
        findings += _counter_gaps(log.streams["wheels"], config)
    if log.has("gps"):
        findings += _gps(log, config, max_speed, timed="gps" not in invented)
    if log.has("gyro") and rates is not None and "gyro" not in invented:
        _gyro_units(log.streams["gyro"], rates, log.streams[odo], config)
    if not findings:
        return log
    old = tuple(getattr(log, "findings", ()) or ())
    return dataclasses.replace(log, findings=old + tuple(findings))


# ------------------------------------------------------------------------------ helpers
def _drive(config):
    """The config's drive model, or None when it cannot be built here (checked elsewhere)."""
    from odofuse.drives import make_drive

    robot = dict(getattr(config, "robot", None) or {})
    if "drive" not in robot:
        return None
    geometry = {k: v for k, v in robot.items() if k not in ("drive", "encoder")}
    try:
        return make_drive(robot["drive"], **geometry)
    except Exception:  # noqa: BLE001 - a bad drive is the config validator's error, not ours
        return None


def _wheel_columns(stream, drive) -> None:
    """``wheels.csv`` holds one column per drive input (docs/formats.md): another column is an
    error naming it (a column the drive does not read was accepted and ignored)."""
    if drive is None or not str(stream.source).endswith(".csv"):
        return
    names = tuple(drive.input_names)
    extra = [c for c in stream.columns if c not in names]
    if extra:
        raise InputError(
            f"unexpected column (the '{drive.name}' drive reads {', '.join(('t', *names))})",
            stream.source,
            1,
            extra[0],
        )


def _step_rates(stream, drive, name: str):
    """``(t_end, dt, |omega| (rad/s), speed (m/s), row)`` (each (N,)) of every step, or None.

    ``row`` is the file row (header = 1) of the step's end.
    """
    names = list(drive.input_names)
    if any(c not in stream.columns for c in names) or len(stream) < 2:
        return None
    values = stream.values[:, [stream.columns.index(c) for c in names]]
    dt = np.diff(stream.t)
    rows = np.arange(3, len(stream) + 2)
    t_end = stream.t[1:]
    if name == "odometry":  # increments since the previous row; row 0 over the median period
        U = values
        dt = np.concatenate([[np.median(dt)], dt])
        rows, t_end = np.arange(2, len(stream) + 2), stream.t
    elif name == "cmd_vel":  # velocities held until the next row
        U = values[:-1] * dt[:, None]
    else:  # cumulative wheel angles; steering angles held during the step
        kinds = getattr(drive, "input_kinds", ("wheel",) * len(names))
        steer = np.array([k == "steer" for k in kinds])
        U = np.where(steer, values[1:], np.diff(values, axis=0))
    try:
        twist = np.asarray(drive.twist(U), dtype=float).reshape(len(U), 3)
    except Exception:  # noqa: BLE001 - a drive without a vectorised twist is not checked
        return None
    ok = dt > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        omega = np.where(ok, np.abs(twist[:, 0]) / np.where(ok, dt, 1.0), 0.0)
        speed = np.where(ok, np.hypot(twist[:, 1], twist[:, 2]) / np.where(ok, dt, 1.0), 0.0)
    return t_end, dt, omega, speed, rows


def _speed(stream, rates, max_speed: float, max_yaw_rate: float, config) -> None:
    _, dt, omega, speed, rows = rates
    bad = (speed > max_speed) | (omega > max_yaw_rate)
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    what = (
        f"speed {speed[i]:.3g} m/s > log.max_speed {max_speed:g}"
        if speed[i] > max_speed
        else f"yaw rate {omega[i]:.3g} rad/s > log.max_yaw_rate {max_yaw_rate:g}"
    )
    hint = "a corrupt row?"
    if stream.name == "wheels":
        robot = getattr(config, "robot", None) or {}
        hint = (
            "encoder ticks read as radians? (no robot.encoder block)"
            if robot.get("encoder") is None
            else "a wrong encoder.rollover, a counter reset or a corrupt row?"
        )
    raise InputError(
        f"the step ending here ({dt[i]:.3g} s) is impossible for this robot: {what} "
        f"({int(bad.sum())} such step(s)); {hint}",
        stream.source,
        int(rows[i]),
        "t",
    )


def _time_units(log, invented=frozenset()) -> None:
    def unit(ratio: float) -> str:
        for name, k in (("nanoseconds", 1e9), ("microseconds", 1e6), ("milliseconds", 1e3)):
            if ratio >= k / 3:
                return name
        return "a different unit"

    timed = [s for s in log.streams.values() if s.name not in invented]
    for s in timed:
        if len(s) and float(np.max(np.abs(s.t))) > MAX_SECONDS:
            i = int(np.argmax(np.abs(s.t)))
            raise InputError(
                f"t = {s.t[i]:.6g} is not seconds (above {MAX_SECONDS:g} s, 3,000 years): "
                f"{unit(abs(s.t[i]) / 1.7e9)} since 1970? odofuse expects seconds",
                s.source,
                i + 2,
                "t",
            )
    ref = next((log.streams[n] for n in ODOMETRY_STREAMS if log.has(n)), None)
    if ref is None or ref.name in invented:
        return
    m_ref = float(np.median(np.abs(ref.t)))
    for s in timed:
        if s is ref or not len(s) or m_ref <= 0:
            continue
        overlap = s.t[0] <= ref.t[-1] and s.t[-1] >= ref.t[0]
        m = float(np.median(np.abs(s.t)))
        if overlap or m <= 0:
            continue
        ratio = m / m_ref
        if ratio >= UNIT_RATIO or ratio <= 1.0 / UNIT_RATIO:
            big = ratio >= UNIT_RATIO
            raise InputError(
                f"times (median {m:.6g}) are {ratio if big else 1 / ratio:.3g} times "
                f"{'larger' if big else 'smaller'} than {ref.name}'s (median {m_ref:.6g}) and "
                f"do not overlap them: {unit(ratio if big else 1 / ratio)} "
                f"{'here' if big else 'in ' + ref.name}? every stream must be in seconds",
                s.source,
                2,
                "t",
            )


def _counter_gaps(stream, config) -> list[Finding]:
    robot = getattr(config, "robot", None) or {}
    enc = robot.get("encoder")
    rollover = getattr(enc, "rollover", None) if enc is not None else None
    if not rollover or len(stream) < 3:
        return []
    half = math.pi * float(rollover) / (float(enc.ticks_per_rev) * float(enc.gear_ratio or 1.0))
    cols = list(enc.columns or [c for c in stream.columns if not c.startswith("steer")])
    idx = [stream.columns.index(c) for c in cols if c in stream.columns]
    if not idx:
        return []
    dt = np.diff(stream.t)
    normal = dt <= 5.0 * np.median(dt)
    if normal.sum() < 2:
        return []
    dphi = np.abs(np.diff(stream.values[:, idx], axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.where(dt[:, None] > 0, dphi / np.where(dt > 0, dt, 1.0)[:, None], 0.0)
    fastest = float(np.max(rate[normal]))
    ambiguous = ~normal & (fastest * dt > half)
    if not ambiguous.any():
        return []
    k = np.flatnonzero(ambiguous)
    return [
        Finding(
            "counter_gap",
            f"{k.size} gap(s) in {stream.source} (longest {dt[k].max():.3g} s, from row "
            f"{k[0] + 2}) in which the wheel could turn more than half the counter range "
            f"(rollover {int(rollover)}) at the fastest rate seen elsewhere "
            f"({fastest:.3g} rad/s): the unwrapped wheel angle across it is ambiguous",
            sensor="wheels",
            t_start=float(stream.t[k[0]]),
            t_end=float(stream.t[k[-1] + 1]),
            figure=float(dt[k].max()),
        )
    ]


def _gps(log, config, max_speed: float, timed: bool = True) -> list[Finding]:
    s = log.streams["gps"]
    out: list[Finding] = []
    if "lat" in s.columns and "lon" in s.columns:
        lat, lon = s["lat"], s["lon"]  # in range: the CSV loader checks that
        opts = (getattr(config, "sensors", None) or {}).get("gps")
        datum = getattr(opts, "datum", None)
        if datum is not None:
            la0, lo0 = float(np.median(lat)), float(np.median(lon))
            d_as_is = math.hypot(la0 - datum[0], lo0 - datum[1])
            d_swapped = math.hypot(lo0 - datum[0], la0 - datum[1])
            if d_as_is > 1.0 and d_swapped < 0.1 * d_as_is:
                raise InputError(
                    f"the fixes (median lat {la0:.6g}, lon {lo0:.6g}) are {d_as_is:.3g} "
                    f"degrees from the datum {tuple(datum[:2])} but match it with lat and lon "
                    "swapped: swap the columns",
                    s.source,
                    1,
                    "lat",
                )
        return out
    if "x" not in s.columns or "y" not in s.columns:
        return out
    xy = np.column_stack([s["x"], s["y"]])
    start = _start_pose(log, config)
    dist = np.hypot(*(xy - start[:2]).T)
    if float(np.median(dist)) > FAR_GPS:
        out.append(
            Finding(
                "gps_far",
                f"the fixes are {np.median(dist):.3g} m (median) from the start pose "
                f"({start[0]:.6g}, {start[1]:.6g}): absolute (e.g. UTM) coordinates without a "
                "local origin? set initial.pose there or subtract the origin",
                sensor="gps",
                t_start=float(s.t[0]),
                t_end=float(s.t[-1]),
                figure=float(np.median(dist)),
            )
        )
    if len(s) > 1 and timed:
        dt = np.diff(s.t)
        step = np.hypot(*np.diff(xy, axis=0).T)
        jumps = (dt > 0) & (step > max_speed * np.where(dt > 0, dt, 1.0))
        if jumps.any():
            k = np.flatnonzero(jumps)
            out.append(
                Finding(
                    "gps_jumps",
                    f"{k.size} fix(es) jump farther than log.max_speed {max_speed:g} m/s "
                    f"allows (largest {step[k].max():.3g} m): left to the gate",
                    sensor="gps",
                    t_start=float(s.t[k[0] + 1]),
                    t_end=float(s.t[k[-1] + 1]),
                    figure=float(k.size),
                    degrades=False,
                )
            )
    return out


def _start_pose(log, config) -> np.ndarray:
    pose = getattr(getattr(config, "initial", None), "pose", None)
    if pose is None:
        pose = getattr(log, "initial_pose", None)
    return np.zeros(3) if pose is None else np.asarray(pose, dtype=float)


#: s, the windows over which :func:`_gyro_units` compares the gyro's heading change with the
#: wheels': long enough that a gyro's white noise averages out (1 s of a 100 Hz gyro with
#: sigma 0.25 rad/s per sample leaves 0.025 rad/s), short enough to follow a turn.
UNITS_WINDOW = 1.0


def _windowed(t_mid, dt, *rates):
    """Each rate averaged over :data:`UNITS_WINDOW` windows of the steps (weighted by ``dt``)."""
    width = max(UNITS_WINDOW, 5.0 * float(np.median(dt)))
    k = np.floor((t_mid - t_mid[0]) / width).astype(np.int64)
    span = np.bincount(k, weights=dt)
    keep = span > 0.5 * width
    return [np.bincount(k, weights=r * dt)[keep] / span[keep] for r in rates]


def _gyro_units(gyro, rates, odo=None, config=None) -> None:
    """Raise when the gyro's yaw rate is not the wheels' in the configured units.

    The two are compared over :data:`UNITS_WINDOW` windows (white noise averages out); where the
    wheels hardly turn, the gyro's median rate (its bias, on a log that mostly drives straight)
    is taken off first, so that a biased gyro beside straight wheels is not read as turning.
    """
    if "wz" not in gyro.columns or len(gyro) < 2:
        return
    t_end, dt, omega, _, _ = rates
    t_mid = t_end - 0.5 * dt
    inside = (t_mid >= gyro.t[0]) & (t_mid <= gyro.t[-1])
    if inside.sum() < 20:
        return
    g_step = np.interp(t_mid[inside], gyro.t, gyro["wz"])
    dt_in = dt[inside]
    g, w = (np.abs(r) for r in _windowed(t_mid[inside], dt_in, g_step, omega[inside]))
    turning = w > 0.05
    if turning.sum() >= 20:
        scale = float(np.sum(g[turning] * w[turning]) / np.sum(w[turning] ** 2))
    else:  # wheels that hardly turn: are they too small for a gyro that does?
        centred = g_step - np.median(g_step)
        g = np.abs(_windowed(t_mid[inside], dt_in, centred)[0])
        # a window's white noise: the step-to-step spread over the steps a window averages
        per_window = max(1.0, g_step.size / max(g.size, 1))
        noise = float(np.std(np.diff(g_step))) / np.sqrt(2.0 * per_window)
        # the gyro turns beyond its noise, and the wheels turn too (only too little): wheels
        # that read straight beside a turning gyro are no unit mistake
        turning = (g > max(0.05, 5.0 * noise)) & (w > 1e-3)
        if turning.sum() < 20:
            return
        scale = float(np.sum(g[turning] ** 2) / max(np.sum(g[turning] * w[turning]), 1e-300))
    if 45.0 <= scale <= 70.0:
        raise InputError(
            f"wz is {scale:.3g} times the wheels' yaw rate ({DEG_PER_RAD:.1f} = degrees per "
            "radian): degrees per second? odofuse expects rad/s",
            gyro.source,
            1,
            "wz",
        )
    robot = getattr(config, "robot", None) or {}
    bound = SKID_WHEEL_SCALE if robot.get("drive") == "skid_steer" else WHEEL_SCALE
    if odo is not None and odo.name == "wheels" and not 1.0 / bound <= scale <= bound:
        _wheel_scale(scale, odo, config)


def _wheel_scale(scale: float, wheels, config) -> None:
    """The wheels' yaw rate is ``1/scale`` of the gyro's: name the keys that set it."""
    robot = getattr(config, "robot", None) or {}
    enc = robot.get("encoder")
    keys = ["robot.wheel_radius", "robot.track_width"]
    if enc is not None:
        keys.insert(0, f"robot.encoder.ticks_per_rev ({enc.ticks_per_rev:g} here)")
    hint = (
        "wheels.csv in metres where radians are expected?"
        if enc is None and scale > 1
        else "encoder ticks read as radians?"
        if enc is None
        else "a wrong encoder scale?"
    )
    raise InputError(
        f"the gyro turns {scale:.3g} times as fast as these wheels say (expected about 1): "
        f"the wheel increments do not fit the configured units; {hint} Check " + ", ".join(keys),
        wheels.source,
        1,
        "left" if "left" in wheels.columns else wheels.columns[0],
    )
