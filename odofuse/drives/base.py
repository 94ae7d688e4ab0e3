"""Drive-model contract and the helpers every drive family shares.

Every drive is a frozen dataclass holding geometry only and satisfying the ``DriveModel``
protocol of ``docs/architecture.md``:

* ``twist(u)``: one step of drive input ``u`` -> body twist ``[omega, v_x, v_y]`` for a step
  of length Delta t = 1 (Modern Robotics 13.4, ``000_96a7e9c96987202e.txt``): omega in rad,
  v_x, v_y in metres, body frame at the start of the step (x forward, y left).
* ``u`` is ``(n,)`` or a batch ``(N, n)``: wheel angle increments in rad (in the order of
  ``input_names``) followed by steering angles in rad (the value held during the step).
* ``J_twist_u(u)`` is the analytic ``(3, n)`` (or ``(N, 3, n)``) Jacobian.
* ``travel(u)`` = ``|u| * travel_scale()`` are the metres rolled by each input's wheel
  (0 for steering angles), the ``|ds_i|`` of the odometry error model.
* ``inverse(twist)`` returns inputs producing ``twist`` (raises ``ValueError`` when the
  drive cannot produce it, e.g. ``v_y != 0`` on a nonholonomic drive).
* ``icr(twist)`` is the instantaneous centre of rotation in the body frame.

Extra class attributes (an extension of the contract): ``input_kinds`` says for each
input whether it is a cumulative wheel angle (``"wheel"``, differenced from ``wheels.csv``),
a steering angle held during the step (``"steer"``, taken as is), a cumulative steering
encoder (``"steer_increment"``, differenced) or an increment read from ``odometry.csv``
(``"increment"``) or a commanded velocity from ``cmd_vel.csv`` (``"velocity"``, times the
row interval); ``degree_of_mobility`` and ``degree_of_steerability`` are Siegwart's
delta_m and delta_s (``004_f4547100a083f338.txt``; see ``docs/drives.md`` for the derivation).
Drives whose inputs include redundant wheels expose ``input_groups``: tuples of input
indices that measure the same travel (used by :func:`odofuse.motion.side_outliers`).

This module owns the base classes (:class:`_Drive`, :class:`_LinearDrive`), input and
geometry validation, :func:`icr` and :func:`turn_drive_turn`; the drive families live in the
sibling modules and the name table in :mod:`odofuse.drives.registry`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from odofuse.errors import ConfigError
from odofuse.se2 import wrap

_REACH_TOL = 1e-9


# --------------------------------------------------------------------------- helpers
def _as_batch(x, n: int, what: str, names: Sequence[str]) -> tuple[np.ndarray, bool]:
    """Return ``x`` as a float ``(N, n)`` array and whether it was a single ``(n,)`` row."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 1 and a.shape[0] == n:
        single = True
        a = a[None, :]
    elif a.ndim == 2 and a.shape[1] == n:
        single = False
    else:
        raise ValueError(
            f"{what}: expected shape ({n},) or (N, {n}) for {tuple(names)}, got {a.shape}"
        )
    if not np.isfinite(a).all():
        row, col = np.argwhere(~np.isfinite(a))[0]
        raise ValueError(f"{what}: non-finite value in row {row}, column '{names[col]}'")
    return a, single


def _twists(twist, what: str) -> tuple[np.ndarray, bool]:
    return _as_batch(twist, 3, what, ("omega", "v_x", "v_y"))


def _out(a: np.ndarray, single: bool) -> np.ndarray:
    return a[0] if single else a


def _check_positive(obj, *names: str) -> None:
    """Validate and convert the named geometry fields to positive finite floats."""
    for key in names:
        val = getattr(obj, key)
        if isinstance(val, bool) or not isinstance(val, (int, float, np.integer, np.floating)):
            raise ConfigError(
                f"{type(obj).__name__}: geometry value must be a number, got {val!r}", key=key
            )
        val = float(val)
        if not (math.isfinite(val) and val > 0.0):
            raise ConfigError(
                f"{type(obj).__name__}: geometry value must be positive and finite, got {val!r}",
                key=key,
            )
        object.__setattr__(obj, key, val)


def _check_real(obj, key: str) -> None:
    val = getattr(obj, key)
    if isinstance(val, bool) or not isinstance(val, (int, float, np.integer, np.floating)):
        raise ConfigError(
            f"{type(obj).__name__}: geometry value must be a number, got {val!r}", key=key
        )
    if not math.isfinite(float(val)):
        raise ConfigError(
            f"{type(obj).__name__}: geometry value must be finite, got {val!r}", key=key
        )
    object.__setattr__(obj, key, float(val))


def icr(twist) -> np.ndarray:
    """Instantaneous centre of rotation of a body twist, in the body frame.

    A rigid body with twist ``[omega, v_x, v_y]`` has zero velocity at the point
    ``p`` with ``v + omega * e_z x p = 0``, i.e. ``p = (-v_y / omega, v_x / omega)``
    (Politecnico slides ``003_...``: ICC at distance ``R = V / omega`` to the left;
    Siegwart ``004_...``).

    Parameters
    ----------
    twist : array_like, shape (3,) or (N, 3)
        Body twist ``[omega, v_x, v_y]`` (rad, m, m per step).

    Returns
    -------
    ndarray, shape (2,) or (N, 2)
        ICR ``[x, y]`` in metres, body frame; ``[inf, inf]`` where ``omega == 0``
        (pure translation or standstill).
    """
    T, single = _twists(twist, "icr")
    out = np.full((T.shape[0], 2), np.inf)
    w = T[:, 0]
    nz = w != 0.0
    out[nz, 0] = -T[nz, 2] / w[nz]
    out[nz, 1] = T[nz, 1] / w[nz]
    return _out(out, single)


def _unreachable(bad: np.ndarray, resid: np.ndarray, name: str, why: str) -> None:
    if bad.any():
        row = int(np.argmax(bad))
        raise ValueError(
            f"{name}.inverse: twist row {row} cannot be produced by this drive ({why}); "
            f"residual {resid[row]:.3g}"
        )


# --------------------------------------------------------------------------- base classes
class _Drive:
    """Shared behaviour: travel from the scale, ICR, input checks."""

    name: ClassVar[str]
    input_names: ClassVar[tuple[str, ...]]
    input_kinds: ClassVar[tuple[str, ...]]
    degree_of_mobility: ClassVar[int]
    degree_of_steerability: ClassVar[int] = 0

    def _u(self, u) -> tuple[np.ndarray, bool]:
        names = self.input_names
        return _as_batch(u, len(names), f"{type(self).__name__}", names)

    def travel_scale(self) -> np.ndarray:
        """``(n,)`` d travel_i / d u_i: metres per radian of wheel angle (0 for steering)."""
        raise NotImplementedError

    def travel(self, u) -> np.ndarray:
        """Metres rolled by each input's wheel, ``|u_i| * travel_scale_i``.

        Parameters
        ----------
        u : array_like, shape (n,) or (N, n)

        Returns
        -------
        ndarray, shape (n,) or (N, n)
            Non-negative; 0 for steering-angle inputs.
        """
        U, single = self._u(u)
        return _out(np.abs(U) * self.travel_scale(), single)

    def icr(self, twist) -> np.ndarray:
        """ICR of ``twist`` in the body frame, ``(2,)`` or ``(N, 2)``; see :func:`icr`."""
        return icr(twist)


class _LinearDrive(_Drive):
    """A drive whose twist is linear in the input, ``twist = F u`` (Modern Robotics 13.4)."""

    def matrix(self) -> np.ndarray:
        """``F`` of ``twist = F u``, shape ``(3, n)``."""
        raise NotImplementedError

    def twist(self, u) -> np.ndarray:
        """Body twist ``[omega, v_x, v_y]`` = ``F u``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        # (F @ U^T)^T: numpy's U @ F^T with a tall, 2-column U is ~40x slower here.
        return _out((self.matrix() @ U.T).T, single)

    def J_twist_u(self, u) -> np.ndarray:
        """Jacobian ``F`` (constant), ``(3, n)`` or ``(N, 3, n)``."""
        U, single = self._u(u)
        J = np.broadcast_to(self.matrix(), (U.shape[0], 3, U.shape[1])).copy()
        return _out(J, single)

    def inverse(self, twist) -> np.ndarray:
        """Inputs producing ``twist``: ``u = pinv(F) twist`` (for omni/mecanum this is H(0)).

        Raises
        ------
        ValueError
            If ``twist`` is not in the range of ``F`` (e.g. ``v_y != 0`` for a
            differential drive), naming the offending row.
        """
        T, single = _twists(twist, f"{type(self).__name__}.inverse")
        F = self.matrix()
        U = T @ np.linalg.pinv(F).T
        resid = np.linalg.norm(U @ F.T - T, axis=1)
        scale = 1.0 + np.linalg.norm(T, axis=1)
        _unreachable(
            resid > _REACH_TOL * scale, resid, type(self).__name__, "outside the range of F"
        )
        return _out(U, single)


def _steered_wheel_inverse(vx_w, vy_w):
    """Rolling speed and steering angle of a wheel whose contact point moves by ``(vx_w, vy_w)``.

    The steering angle is kept in ``(-pi/2, pi/2]`` and the rolling speed takes the sign of
    ``vx_w`` (a wheel that moves backwards rolls backwards rather than steering by pi).
    """
    s = np.where(vx_w < 0.0, -1.0, 1.0)
    delta = np.arctan2(s * vy_w, s * vx_w)
    speed = s * np.hypot(vx_w, vy_w)
    return speed, delta


def _nonholonomic_vy(T: np.ndarray, name: str) -> None:
    scale = 1.0 + np.linalg.norm(T, axis=1)
    resid = np.abs(T[:, 2])
    _unreachable(resid > _REACH_TOL * scale, resid, name, "v_y must be 0 at the rear axle")


# --------------------------------------------------------------------------- inverse kinematics
def turn_drive_turn(start_pose, goal_pose) -> np.ndarray:
    """Turn-drive-turn inverse kinematics (Politecnico slides ``003_...``).

    1. rotate on the spot to face the goal position, 2. drive straight to it,
    3. rotate to the goal heading. Turns are wrapped to ``[-pi, pi)`` (the shorter way).

    Parameters
    ----------
    start_pose, goal_pose : array_like, shape (3,)
        ``[x, y, theta]`` in the world frame (m, m, rad).

    Returns
    -------
    ndarray, shape (3, 3)
        Three body twists (one per row, Delta t = 1): ``[omega1, 0, 0]``,
        ``[0, dist, 0]``, ``[omega2, 0, 0]``. When the positions coincide the first turn is 0
        and the whole rotation is in the last segment.
    """
    p0 = np.asarray(start_pose, dtype=float)
    p1 = np.asarray(goal_pose, dtype=float)
    for what, p in (("start_pose", p0), ("goal_pose", p1)):
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(
                f"turn_drive_turn: {what} must be a finite (3,) [x, y, theta], got {p!r}"
            )
    dx, dy = p1[:2] - p0[:2]
    dist = float(np.hypot(dx, dy))
    if dist == 0.0:
        heading = p0[2]
    else:
        heading = math.atan2(dy, dx)
    turn1 = float(wrap(heading - p0[2]))
    turn2 = float(wrap(p1[2] - heading))
    return np.array([[turn1, 0.0, 0.0], [0.0, dist, 0.0], [turn2, 0.0, 0.0]])
