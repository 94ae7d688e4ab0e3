"""Steered wheels: synchro, tricycle, bicycle and four-wheel Ackermann drives.

Sources: the Politecnico slides (``003_73fced8ec7c15fe5.txt``) for each model's kinematics,
Modern Robotics eq. 13.5 for the rolling constraint of a steered wheel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from odofuse.drives.base import (
    _REACH_TOL,
    _check_positive,
    _Drive,
    _LinearDrive,
    _nonholonomic_vy,
    _out,
    _steered_wheel_inverse,
    _twists,
    _unreachable,
)


@dataclass(frozen=True)
class Synchro(_LinearDrive):
    """Synchronous drive, Politecnico slides (``003_...``): v and omega controlled directly.

    All wheels are driven by one motor and steered together by a second; the slides
    integrate it as ``x' = v cos(theta)``, ``y' = v sin(theta)``, ``theta' = omega`` with
    ``theta`` the (common) wheel direction. The body frame is therefore the steering
    (turret) frame, aligned with the wheels, and the inputs are

    * ``drive``: wheel angle increment, rad (``v_x = r * drive``),
    * ``steer``: increment of the steering motor angle over the step, rad (``omega = steer``).

    Both come from cumulative encoders (``input_kinds = ("wheel", "steer_increment")``):
    an absolute steering angle would carry no information in the turret frame (it is 0 by
    construction), the rotation over the step is what moves the frame. The steering increment
    is an odometric measurement in its own right, so its ``travel_scale`` is 1 (rad), like the
    ``dtheta`` of :class:`Increments`, and the error model can give it a variance.

    Parameters
    ----------
    wheel_radius : float
        m.
    """

    wheel_radius: float

    name: ClassVar[str] = "synchro"
    input_names: ClassVar[tuple[str, ...]] = ("drive", "steer")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "steer_increment")
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius")

    def matrix(self) -> np.ndarray:
        return np.array([[0.0, 1.0], [self.wheel_radius, 0.0], [0.0, 0.0]])

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius, 1.0])


@dataclass(frozen=True)
class Tricycle(_Drive):
    r"""Tricycle (AGV): one steered, driven front wheel; Politecnico slides (``003_...``).

    Body frame at the midpoint of the passive rear axle; the steered wheel is ``d``
    ahead of it. With ``V_s = r * wheel`` and steering angle ``a``:

    .. math::

        \omega = \frac{V_s}{d}\sin a,\quad v_x = V_s \cos a,\quad v_y = 0.

    ``a = 0`` drives straight, ``a = +-pi/2`` rotates in place about the rear axle midpoint.

    Parameters
    ----------
    wheel_radius : float
        Steered wheel radius, m.
    wheelbase : float
        d, rear axle to steered wheel, m.
    """

    wheel_radius: float
    wheelbase: float

    name: ClassVar[str] = "tricycle"
    input_names: ClassVar[tuple[str, ...]] = ("wheel", "steer")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "steer")
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheelbase")

    def twist(self, u) -> np.ndarray:
        """``[V_s sin(a) / d, V_s cos(a), 0]``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        V = self.wheel_radius * U[:, 0]
        a = U[:, 1]
        T = np.stack([V * np.sin(a) / self.wheelbase, V * np.cos(a), np.zeros_like(V)], axis=1)
        return _out(T, single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, 2)`` or ``(N, 3, 2)``; smooth for every steering angle."""
        U, single = self._u(u)
        r, d = self.wheel_radius, self.wheelbase
        V, a = r * U[:, 0], U[:, 1]
        J = np.zeros((U.shape[0], 3, 2))
        J[:, 0, 0] = r * np.sin(a) / d
        J[:, 0, 1] = V * np.cos(a) / d
        J[:, 1, 0] = r * np.cos(a)
        J[:, 1, 1] = -V * np.sin(a)
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius, 0.0])

    def inverse(self, twist) -> np.ndarray:
        """``(wheel, steer)`` with ``steer`` in ``(-pi/2, pi/2]``; 0 for a standstill.

        Raises ``ValueError`` for ``v_y != 0`` (the rear axle cannot slide sideways).
        """
        T, single = _twists(twist, "Tricycle.inverse")
        _nonholonomic_vy(T, "Tricycle")
        speed, steer = _steered_wheel_inverse(T[:, 1], T[:, 0] * self.wheelbase)
        return _out(np.stack([speed / self.wheel_radius, steer], axis=1), single)


@dataclass(frozen=True)
class Bicycle(_Drive):
    r"""Bicycle approximation of a car, Politecnico slides (``003_...``).

    ``V`` is the speed at the rear axle midpoint (the body origin), ``V = r * rear`` where
    ``rear`` is the angle increment of a virtual rear wheel (the mean of the two rear wheels);
    ``a`` is the virtual front wheel's steering angle and ``d`` the wheelbase:

    .. math::

        \omega = V \frac{\tan a}{d},\quad v_x = V,\quad v_y = 0.

    The model is singular at ``a = +-pi/2`` (use :class:`Tricycle` there); such inputs raise
    ``ValueError``.

    Parameters
    ----------
    wheel_radius : float
        Rear wheel radius, m.
    wheelbase : float
        d, rear to front axle, m.
    """

    wheel_radius: float
    wheelbase: float

    name: ClassVar[str] = "bicycle"
    input_names: ClassVar[tuple[str, ...]] = ("rear", "steer")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "steer")
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheelbase")

    def _u(self, u):
        U, single = super()._u(u)
        bad = np.abs(U[:, 1]) >= 0.5 * np.pi - 1e-9
        if bad.any():
            row = int(np.argmax(bad))
            raise ValueError(
                f"Bicycle: steering angle {U[row, 1]!r} in row {row}, column 'steer' is at or "
                "beyond +-pi/2 where tan(a) is singular"
            )
        return U, single

    def twist(self, u) -> np.ndarray:
        """``[V tan(a) / d, V, 0]``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        V = self.wheel_radius * U[:, 0]
        T = np.stack([V * np.tan(U[:, 1]) / self.wheelbase, V, np.zeros_like(V)], axis=1)
        return _out(T, single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, 2)`` or ``(N, 3, 2)``."""
        U, single = self._u(u)
        r, d = self.wheel_radius, self.wheelbase
        V, a = r * U[:, 0], U[:, 1]
        J = np.zeros((U.shape[0], 3, 2))
        J[:, 0, 0] = r * np.tan(a) / d
        J[:, 0, 1] = V / (d * np.cos(a) ** 2)
        J[:, 1, 0] = r
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius, 0.0])

    def inverse(self, twist) -> np.ndarray:
        """``(rear, steer)`` with ``tan(steer) = omega d / v_x``.

        Raises ``ValueError`` for ``v_y != 0`` or for a rotation without forward motion
        (``v_x = 0``, ``omega != 0``), which needs ``steer = pi/2``.
        """
        T, single = _twists(twist, "Bicycle.inverse")
        _nonholonomic_vy(T, "Bicycle")
        w, vx = T[:, 0], T[:, 1]
        scale = 1.0 + np.linalg.norm(T, axis=1)
        _unreachable(
            (vx == 0.0) & (np.abs(w) > _REACH_TOL * scale),
            np.abs(w),
            "Bicycle",
            "turning on the spot needs steer = pi/2",
        )
        s = np.where(vx < 0.0, -1.0, 1.0)
        steer = np.arctan2(s * w * self.wheelbase, s * vx)
        return _out(np.stack([vx / self.wheel_radius, steer], axis=1), single)


@dataclass(frozen=True)
class Ackermann(_Drive):
    r"""Car with Ackermann steering, per-wheel kinematics of the Politecnico slides (``003_...``).

    Body frame at the rear axle midpoint, x forward, y left; ``b = track_width / 2``,
    ``d = wheelbase``. Wheels: front-left ``(d, b)`` and front-right ``(d, -b)`` steered by
    ``steer_left``/``steer_right``, rear-left ``(0, b)`` and rear-right ``(0, -b)`` fixed.
    The two fixed rear wheels force ``v_y = 0`` (their no-side-slip constraints). A wheel at
    ``(x_i, y_i)`` steered by ``delta_i`` rolls by

    .. math::

        r\,\Delta\phi_i = \cos\delta_i\,v_x + (x_i\sin\delta_i - y_i\cos\delta_i)\,\omega

    (the ``h_i`` rows of Modern Robotics 13.5 with ``gamma = 0``). Forward kinematics fuses the
    four rolling constraints by unweighted least squares over ``(omega, v_x)``:
    ``z = (A^T A)^{-1} A^T s`` with ``A`` the ``(4, 2)`` matrix of the rows above and
    ``s = r Delta phi`` (maximum likelihood for equal, independent wheel noise); for consistent
    inputs the residual is zero and this is the slides' exact kinematics
    (``omega (R +- b) = V_B{L,R}``, ``omega d / sin(alpha) = V_F``). The steering angles enter
    only through ``A``; the Jacobian differentiates the least-squares solution analytically.

    Inverse kinematics returns the four wheel increments and both Ackermann steering angles
    ``tan(delta_{L,R}) = d / (R -+ b)`` with ``R = v_x / omega`` (left turn positive); the ICR is
    ``(0, R)``, on the rear axle line.

    Parameters
    ----------
    wheel_radius : float
        m, all four wheels.
    wheelbase : float
        d, rear to front axle, m.
    track_width : float
        2b, left to right wheel, m.
    """

    wheel_radius: float
    wheelbase: float
    track_width: float

    name: ClassVar[str] = "ackermann"
    input_names: ClassVar[tuple[str, ...]] = (
        "front_left",
        "front_right",
        "rear_left",
        "rear_right",
        "steer_left",
        "steer_right",
    )
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel",) * 4 + ("steer",) * 2
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheelbase", "track_width")

    def _design(self, dl: np.ndarray, dr: np.ndarray):
        """Rows ``A (N, 4, 2)`` over ``(omega, v_x)`` and their steering derivatives."""
        d, b = self.wheelbase, 0.5 * self.track_width
        N = dl.shape[0]
        A = np.empty((N, 4, 2))
        A[:, 0] = np.stack([d * np.sin(dl) - b * np.cos(dl), np.cos(dl)], axis=1)
        A[:, 1] = np.stack([d * np.sin(dr) + b * np.cos(dr), np.cos(dr)], axis=1)
        A[:, 2] = (-b, 1.0)
        A[:, 3] = (b, 1.0)
        dA_l = np.stack([d * np.cos(dl) + b * np.sin(dl), -np.sin(dl)], axis=1)
        dA_r = np.stack([d * np.cos(dr) - b * np.sin(dr), -np.sin(dr)], axis=1)
        return A, dA_l, dA_r

    def _solve(self, U: np.ndarray):
        s = self.wheel_radius * U[:, :4]
        A, dA_l, dA_r = self._design(U[:, 4], U[:, 5])
        At = np.swapaxes(A, 1, 2)
        G = At @ A  # (N, 2, 2); always invertible: the rear rows alone have rank 2
        z = np.linalg.solve(G, (At @ s[:, :, None]))[:, :, 0]
        return z, s, A, At, G, dA_l, dA_r

    def twist(self, u) -> np.ndarray:
        """Least-squares twist ``[omega, v_x, 0]``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        z = self._solve(U)[0]
        return _out(np.column_stack([z, np.zeros(len(z))]), single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, 6)`` or ``(N, 3, 6)``.

        With ``G = A^T A`` and residual ``e = s - A z``: ``dz/ds = G^{-1} A^T`` and, for a
        steering angle changing row ``k`` of ``A`` by ``a_k'``,
        ``dz/d delta = G^{-1} (a_k' e_k - a_k (a_k' . z))``.
        """
        U, single = self._u(u)
        z, s, A, At, G, dA_l, dA_r = self._solve(U)
        N = U.shape[0]
        e = s - (A @ z[:, :, None])[:, :, 0]
        rhs = np.empty((N, 2, 6))
        rhs[:, :, :4] = At * self.wheel_radius
        for col, k, da in ((4, 0, dA_l), (5, 1, dA_r)):
            rhs[:, :, col] = da * e[:, k : k + 1] - A[:, k] * np.sum(da * z, axis=1, keepdims=True)
        Jz = np.linalg.solve(G, rhs)
        J = np.concatenate([Jz, np.zeros((N, 1, 6))], axis=1)
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius] * 4 + [0.0, 0.0])

    def inverse(self, twist) -> np.ndarray:
        """Wheel increments of all four wheels and both steering angles for ``twist``.

        Steering angles lie in ``(-pi/2, pi/2]``; a front wheel whose contact point moves
        backwards rolls backwards. Raises ``ValueError`` for ``v_y != 0``.
        """
        T, single = _twists(twist, "Ackermann.inverse")
        _nonholonomic_vy(T, "Ackermann")
        w, vx = T[:, 0], T[:, 1]
        d, b, r = self.wheelbase, 0.5 * self.track_width, self.wheel_radius
        s_fl, d_l = _steered_wheel_inverse(vx - w * b, w * d)
        s_fr, d_r = _steered_wheel_inverse(vx + w * b, w * d)
        out = np.stack([s_fl / r, s_fr / r, (vx - w * b) / r, (vx + w * b) / r, d_l, d_r], axis=1)
        return _out(out, single)
