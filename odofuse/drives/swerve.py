r"""Swerve drive: N modules, each steered and driven (WPILib's ``SwerveDriveKinematics``).

Module ``i`` sits at ``(x_i, y_i)`` in the body frame (x forward, y left, metres), rolls by
``d_i = r_i Delta phi_i`` (wheel angle increment ``Delta phi_i``, rad) along its steering
angle ``s_i`` (rad from the body x axis, counter-clockwise; the angle held during the step).
A rigid twist ``z = [omega, v_x, v_y]`` moves the module's contact point by

.. math::

    \begin{bmatrix} d_i\cos s_i \\ d_i\sin s_i \end{bmatrix}
    = \begin{bmatrix} -y_i & 1 & 0 \\ x_i & 0 & 1 \end{bmatrix} z = A_i z ,

(Modern Robotics eq. 13.5 with ``gamma = 0``; WPILib's inverse-kinematics matrix), so forward
kinematics is the least-squares solution ``z = A^+ b`` over the ``2N`` stacked rows, with
``b = [d_1 c_1, d_1 s_1, ...]`` (maximum likelihood for equal, independent errors in both
components; exact for consistent inputs). ``A`` depends on the geometry only, so the
Jacobian is analytic and cheap:

.. math::

    \frac{\partial z}{\partial \Delta\phi_i} = r_i (P_{:,2i}\cos s_i + P_{:,2i+1}\sin s_i),\quad
    \frac{\partial z}{\partial s_i} = d_i (-P_{:,2i}\sin s_i + P_{:,2i+1}\cos s_i),

with ``P = A^+``. For a constant twist a module's direction in the body frame is constant
over the step and its wheel rolls ``|A_i z|``, so ``z`` is exactly the twist exponential
coordinate of the step (the exact integrator reproduces a noise-free drive exactly).

Inverse kinematics gives each module's speed ``|A_i z|`` and angle ``atan2`` of ``A_i z``,
keeps the previous angle of a module at zero speed (WPILib ``ConserveWheelAngle``), applies
the shortest-rotation flip (``SwerveModuleState.optimize``: turn by at most 90 degrees and
reverse the wheel instead) and optionally scales all wheel speeds down together so the
fastest equals a maximum (WPILib ``desaturateWheelSpeeds``), which keeps the twist's direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

from odofuse.drives.base import _REACH_TOL, _Drive, _out, _twists
from odofuse.errors import ConfigError
from odofuse.se2 import wrap


def desaturate(speeds, max_speed: float) -> np.ndarray:
    """Scale each row of wheel speeds so that its largest magnitude is at most ``max_speed``.

    All wheels of a row share one factor ``max_speed / max_i |speed_i|`` (WPILib
    ``SwerveDriveKinematics.desaturateWheelSpeeds``), so the body twist keeps its direction
    and only slows down; rows already within the limit are unchanged.

    Parameters
    ----------
    speeds : array_like, shape (n,) or (N, n)
        Signed wheel speeds (any unit: m/s, rad per step...).
    max_speed : float
        Positive limit in the same unit.

    Returns
    -------
    ndarray, same shape as ``speeds``
    """
    if not (np.isfinite(max_speed) and max_speed > 0):
        raise ValueError(f"desaturate: max_speed must be positive and finite, got {max_speed!r}")
    s = np.asarray(speeds, dtype=float)
    S = np.atleast_2d(s)
    peak = np.max(np.abs(S), axis=1, keepdims=True)
    factor = np.where(peak > max_speed, max_speed / np.where(peak > 0, peak, 1.0), 1.0)
    return (S * factor).reshape(s.shape)


def optimize_angles(angles, current=None) -> tuple[np.ndarray, np.ndarray]:
    """Shortest-rotation flip of module angles along a sequence of steps.

    Row ``k`` of ``angles`` is replaced by whichever of ``a`` and ``a + pi`` is within 90
    degrees of row ``k-1``'s result (row 0 against ``current``), the rule of WPILib's
    ``SwerveModuleState.optimize``; a flipped module drives its wheel backwards. Done at once
    for all rows by unwrapping ``2 a`` (a jump of ``2 a`` by more than pi is a flip).

    Parameters
    ----------
    angles : array_like, shape (N, m)
        Module angles, rad, per step (row) and module (column).
    current : array_like, shape (m,), optional
        Angles before the first row (default 0: all modules pointing forward).

    Returns
    -------
    optimized : ndarray, shape (N, m)
        Angles wrapped to ``[-pi, pi)``.
    sign : ndarray, shape (N, m)
        ``+1`` or ``-1``: multiply the module's speed by it.
    """
    a = np.atleast_2d(np.asarray(angles, dtype=float))
    c = np.zeros(a.shape[1]) if current is None else np.asarray(current, dtype=float)
    b = np.unwrap(np.vstack([2.0 * c[None, :], 2.0 * a]), axis=0)[1:]
    flips = np.rint((0.5 * b - a) / np.pi)
    sign = np.where(np.mod(flips, 2.0) == 1.0, -1.0, 1.0)
    return wrap(0.5 * b), sign


@dataclass(frozen=True)
class Swerve(_Drive):
    """Swerve drive with ``N >= 2`` modules (equations in the module docstring).

    Inputs (``wheels.csv`` columns): ``w1 .. wN`` cumulative wheel angles (rad), then
    ``s1 .. sN`` each module's steering angle held during the step (rad, 0 = body x axis,
    counter-clockwise), in the order of ``modules``.

    Parameters
    ----------
    wheel_radius : float or sequence of float
        m, one for all modules or one per module.
    modules : sequence of (x_i, y_i)
        Module contact points in the body frame, m. WPILib's usual order is front-left,
        front-right, back-left, back-right, e.g. ``[[l, w], [l, -w], [-l, w], [-l, -w]]``.
    """

    wheel_radius: Any
    modules: Any

    name: ClassVar[str] = "swerve"
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 2

    def __post_init__(self) -> None:
        try:
            pos = np.asarray(self.modules, dtype=float)
            r = np.asarray(self.wheel_radius, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ConfigError(
                f"Swerve: modules and wheel_radius must be numeric ({exc})", key="modules"
            ) from None
        if pos.ndim != 2 or pos.shape[1] != 2 or pos.shape[0] < 2:
            raise ConfigError(
                f"Swerve: modules must be a list of at least two [x, y] pairs, got shape "
                f"{pos.shape}",
                key="modules",
            )
        n = pos.shape[0]
        if not np.isfinite(pos).all():
            raise ConfigError("Swerve: module positions must be finite", key="modules")
        if r.ndim == 0:
            r = np.full(n, float(r))
        if r.shape != (n,) or not (np.isfinite(r).all() and (r > 0).all()):
            raise ConfigError(
                f"Swerve: wheel_radius must be one positive number or {n} of them",
                key="wheel_radius",
            )
        if np.linalg.matrix_rank(_design(pos)) < 3:
            raise ConfigError("Swerve: modules must not all be at one point", key="modules")
        object.__setattr__(self, "modules", tuple(map(tuple, pos.tolist())))
        object.__setattr__(self, "wheel_radius", tuple(r.tolist()))

    @property
    def n_modules(self) -> int:
        return len(self.modules)

    @property
    def input_names(self) -> tuple[str, ...]:  # type: ignore[override]
        n = self.n_modules
        return tuple(f"w{i + 1}" for i in range(n)) + tuple(f"s{i + 1}" for i in range(n))

    @property
    def input_kinds(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("wheel",) * self.n_modules + ("steer",) * self.n_modules

    @cached_property
    def _pinv(self) -> tuple[np.ndarray, np.ndarray]:
        """Columns of ``P = A^+`` for the x and the y row of each module, each ``(3, N)``."""
        P = np.linalg.pinv(_design(np.asarray(self.modules)))
        return P[:, 0::2], P[:, 1::2]

    def twist(self, u) -> np.ndarray:
        """Least-squares twist ``[omega, v_x, v_y]``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        n = self.n_modules
        d = U[:, :n] * np.asarray(self.wheel_radius)
        c, s = np.cos(U[:, n:]), np.sin(U[:, n:])
        Px, Py = self._pinv
        return _out((d * c) @ Px.T + (d * s) @ Py.T, single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, 2N)`` or ``(N, 3, 2N)`` (wheel increments, then angles)."""
        U, single = self._u(u)
        n = self.n_modules
        r = np.asarray(self.wheel_radius)
        d = U[:, :n] * r
        c, s = np.cos(U[:, n:]), np.sin(U[:, n:])
        Px, Py = self._pinv
        J = np.empty((U.shape[0], 3, 2 * n))
        J[:, :, :n] = Px[None] * (r * c)[:, None, :] + Py[None] * (r * s)[:, None, :]
        J[:, :, n:] = Py[None] * (d * c)[:, None, :] - Px[None] * (d * s)[:, None, :]
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.concatenate([np.asarray(self.wheel_radius), np.zeros(self.n_modules)])

    def module_velocities(self, twist) -> np.ndarray:
        """Contact-point displacement ``A_i z`` of every module, ``(N, n_modules, 2)``, m."""
        T, _ = _twists(twist, "Swerve.module_velocities")
        pos = np.asarray(self.modules)
        vx = T[:, 1:2] - T[:, 0:1] * pos[None, :, 1]
        vy = T[:, 2:3] + T[:, 0:1] * pos[None, :, 0]
        return np.stack([vx, vy], axis=-1)

    def inverse(self, twist, current=None, optimize: bool = True, max_increment=None):
        """Wheel increments and module angles producing ``twist``, row by row.

        Parameters
        ----------
        twist : array_like, shape (3,) or (N, 3)
        current : array_like, shape (n_modules,), optional
            Module angles before the first row (default 0).
        optimize : bool
            Apply the shortest-rotation flip against the previous row (``current`` for the
            first); without it angles are ``atan2`` in ``[-pi, pi)`` and speeds >= 0.
        max_increment : float, optional
            Largest wheel angle increment per step, rad; faster rows are slowed down by
            :func:`desaturate` (then the returned inputs produce a scaled-down twist).

        Returns
        -------
        ndarray, shape (2 n_modules,) or (N, 2 n_modules)
            ``w1 .. wN`` (rad) then ``s1 .. sN`` (rad). A module at zero speed keeps the
            previous row's angle (``current`` for the first row).
        """
        T, single = _twists(twist, "Swerve.inverse")
        n = self.n_modules
        V = self.module_velocities(T)
        speed = np.hypot(V[..., 0], V[..., 1])
        angle = np.arctan2(V[..., 1], V[..., 0])
        start = np.zeros(n) if current is None else np.asarray(current, dtype=float)
        if start.shape != (n,) or not np.isfinite(start).all():
            raise ValueError(f"Swerve.inverse: current must be {n} finite angles, got {current!r}")
        still = speed <= _REACH_TOL * (1.0 + np.linalg.norm(T, axis=1, keepdims=True))
        # Hold the last moving row's angle through standstills (forward fill).
        rows = np.where(~still, np.arange(len(T))[:, None] + 1, 0)
        rows = np.maximum.accumulate(rows, axis=0)
        held = np.vstack([start[None, :], angle])[rows, np.arange(n)[None, :]]
        speed = np.where(still, 0.0, speed)
        if optimize:
            angle, sign = optimize_angles(held, start)
            speed = speed * sign
        else:
            angle = wrap(held)
        inc = speed / np.asarray(self.wheel_radius)
        if max_increment is not None:
            inc = desaturate(inc, float(max_increment))
        return _out(np.concatenate([inc, angle], axis=1), single)


def _design(pos: np.ndarray) -> np.ndarray:
    """``A`` ``(2N, 3)``: rows ``[-y_i, 1, 0]`` and ``[x_i, 0, 1]`` over ``[omega, v_x, v_y]``."""
    n = pos.shape[0]
    A = np.zeros((2 * n, 3))
    A[0::2, 0], A[0::2, 1] = -pos[:, 1], 1.0
    A[1::2, 0], A[1::2, 2] = pos[:, 0], 1.0
    return A
