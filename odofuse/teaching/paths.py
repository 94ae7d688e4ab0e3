"""Path generators of the simulator: a manoeuvre -> one commanded body twist per step.

Squares (Borenstein's UMBmark, clockwise or counter-clockwise), the figure eight, waypoint tours
driven turn-drive-turn (Politecnico slides ``003_73fced8ec7c15fe5.txt``) and explicit twist
lists; twists are ``[omega, v_x, v_y]`` per step of ``dt`` seconds (:func:`path_twists`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from odofuse.teaching.scenario import PATH_KINDS

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
