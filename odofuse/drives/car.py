r"""Cars measured as ros2_controllers measures them: two rear encoders and the steering.

ros2_controllers' ``steering_controllers_library`` (``steering_kinematics.cpp``,
``SteeringKinematics::update_from_velocity``) serves the tricycle steering controller (two
rear traction wheels, one steering joint) and the Ackermann steering controller (two rear
traction wheels, two steering joints); the front wheels carry no encoder. Body frame at the
rear axle midpoint, x forward, y left; ``L = wheelbase``, ``a = track_width / 2`` (rear,
traction track), ``r = wheel_radius``.

**One steering angle** ``phi`` (the virtual bicycle wheel at the front axle midpoint, left
turn positive), drive ``car``: the turning radius is ``R = L / tan(phi)`` and each rear
wheel's rolled distance ``r Delta theta`` is corrected to the axle midpoint before averaging,

.. math::

    v = \tfrac12\Big(r\Delta\theta_R \frac{R}{R + a} + r\Delta\theta_L \frac{R}{R - a}\Big)
      = \tfrac r2\, L\cos\phi\Big(\frac{\Delta\theta_R}{L\cos\phi + a\sin\phi}
        + \frac{\Delta\theta_L}{L\cos\phi - a\sin\phi}\Big),\qquad
    \omega = v\,\frac{\tan\phi}{L}, \quad v_y = 0.

(ros2_controllers ``get_linear_velocity_double_traction_axle``; with ``phi = 0`` this is the
plain mean.) The second form, used here, is smooth through ``phi = +-pi/2`` (turning about the
rear axle midpoint, where it becomes the differential drive ``omega = r (Delta theta_R -
Delta theta_L) / (2a)``) and singular only where an inner rear wheel sits at the ICR
(``L cos phi = +-a sin phi``, ``|R| = a``), which raises ``ValueError``.

**Two steering angles** ``delta_L, delta_R`` (drive ``car_ackermann``): each is first mapped to
the virtual bicycle angle it implies for front wheels ``+-b`` off the centre line
(``b = steering_track_width / 2``),

.. math::

    \phi_L = \arctan\frac{L\tan\delta_L}{L + b\tan\delta_L},\qquad
    \phi_R = \arctan\frac{L\tan\delta_R}{L - b\tan\delta_R},\qquad
    \phi = \tfrac12(\phi_L + \phi_R),

then as above (ros2_controllers' four-argument ``update_from_velocity``). Computed as
``atan2(L sin delta, L cos delta +- b sin delta)`` folded into ``[-pi/2, pi/2]``, whose
derivative is ``L^2 / (x^2 + y^2)`` of its two arguments.

Conventions against ros2_controllers: their functions take the right wheel first; their
``wheel_track`` / ``traction_track_width`` is our ``track_width`` (2a), their
``wheelbase`` our ``wheelbase``, their ``traction_wheels_radius`` our ``wheel_radius``; they
integrate velocities times ``dt``, we take the wheel angle increments of the step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from odofuse.drives.base import (
    _REACH_TOL,
    _check_positive,
    _Drive,
    _nonholonomic_vy,
    _out,
    _steered_wheel_inverse,
    _twists,
    _unreachable,
)

# Relative distance of an inner rear wheel from the ICR below which the correction is refused.
_ICR_TOL = 1e-9


def _rear_axle(r, L, a, dl, dr, phi, name):
    """``omega, v`` from the rear wheels and the virtual steering angle, with partials.

    Returns ``w, v, (dw_dl, dw_dr, dw_dphi), (dv_dl, dv_dr, dv_dphi)``, all ``(N,)``.
    """
    c, s = np.cos(phi), np.sin(phi)
    Dr, Dl = L * c + a * s, L * c - a * s
    bad = (np.abs(Dr) < _ICR_TOL * L) | (np.abs(Dl) < _ICR_TOL * L)
    if bad.any():
        row = int(np.argmax(bad))
        raise ValueError(
            f"{name}: steering angle {phi[row]!r} in row {row} puts a rear wheel at the "
            "instantaneous centre of rotation (|R| = track_width / 2); the per-wheel "
            "correction R / (R +- track_width / 2) is undefined there"
        )
    A = dr / Dr + dl / Dl
    B = dr * (a * c - L * s) / Dr**2 - dl * (a * c + L * s) / Dl**2  # dA/dphi = -B
    h = 0.5 * r
    v, w = h * L * c * A, h * s * A
    dv = (h * L * c / Dl, h * L * c / Dr, h * L * (-s * A - c * B))
    dw = (h * s / Dl, h * s / Dr, h * (c * A - s * B))
    return w, v, dw, dv


@dataclass(frozen=True)
class Car(_Drive):
    """Rear-encoder car with one steering angle (ros2_controllers' tricycle steering).

    Inputs: ``rear_left``, ``rear_right`` (cumulative wheel angles, rad) and ``steer`` (the
    virtual bicycle steering angle at the front axle midpoint held during the step, rad,
    left positive). Equations in the module docstring.

    Parameters
    ----------
    wheel_radius : float
        Rear (traction) wheel radius, m.
    wheelbase : float
        L, rear to front axle, m.
    track_width : float
        2a, rear left to rear right wheel, m.
    """

    wheel_radius: float
    wheelbase: float
    track_width: float

    name: ClassVar[str] = "car"
    input_names: ClassVar[tuple[str, ...]] = ("rear_left", "rear_right", "steer")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "wheel", "steer")
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheelbase", "track_width")

    def _phi(self, U):
        """Virtual steering angle ``(N,)`` and its gradient over the steering inputs."""
        return U[:, 2], np.ones((U.shape[0], 1))

    def _solve(self, U):
        phi, dphi = self._phi(U)
        w, v, dw, dv = _rear_axle(
            self.wheel_radius,
            self.wheelbase,
            0.5 * self.track_width,
            U[:, 0],
            U[:, 1],
            phi,
            type(self).__name__,
        )
        return w, v, dw, dv, dphi

    def twist(self, u) -> np.ndarray:
        """``[omega, v, 0]`` at the rear axle midpoint; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        w, v = self._solve(U)[:2]
        return _out(np.stack([w, v, np.zeros_like(v)], axis=1), single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, n)`` or ``(N, 3, n)``."""
        U, single = self._u(u)
        _, _, dw, dv, dphi = self._solve(U)
        J = np.zeros((U.shape[0], 3, U.shape[1]))
        for row, d in ((0, dw), (1, dv)):
            J[:, row, 0], J[:, row, 1] = d[0], d[1]
            J[:, row, 2:] = d[2][:, None] * dphi
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius] * 2 + [0.0] * (len(self.input_names) - 2))

    def _rear_inverse(self, T):
        _nonholonomic_vy(T, type(self).__name__)
        a, r = 0.5 * self.track_width, self.wheel_radius
        w, vx = T[:, 0], T[:, 1]
        return (vx - w * a) / r, (vx + w * a) / r

    def inverse(self, twist) -> np.ndarray:
        """``(rear_left, rear_right, steer)`` with ``steer`` in ``(-pi/2, pi/2]``.

        ``tan(steer) = omega L / v_x``; turning on the spot gives ``steer = pi/2`` (the rear
        wheels then turn in opposite directions). Raises ``ValueError`` for ``v_y != 0``.
        """
        T, single = _twists(twist, "Car.inverse")
        left, right = self._rear_inverse(T)
        _, steer = _steered_wheel_inverse(T[:, 1], T[:, 0] * self.wheelbase)
        return _out(np.stack([left, right, steer], axis=1), single)


@dataclass(frozen=True)
class CarAckermann(Car):
    """Rear-encoder car with two steering angles (ros2_controllers' Ackermann steering).

    Inputs: ``rear_left``, ``rear_right`` (rad, cumulative), ``steer_left``, ``steer_right``
    (front wheel steering angles held during the step, rad, left positive).

    Parameters
    ----------
    wheel_radius, wheelbase, track_width : float
        As :class:`Car` (``track_width`` is the rear, traction track).
    steering_track_width : float, optional
        2b, distance between the steering axes of the front wheels, m (default
        ``track_width``, as ros2_controllers' three-argument ``set_wheel_params``).
    """

    steering_track_width: float | None = None

    name: ClassVar[str] = "car_ackermann"
    input_names: ClassVar[tuple[str, ...]] = (
        "rear_left",
        "rear_right",
        "steer_left",
        "steer_right",
    )
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "wheel", "steer", "steer")

    def __post_init__(self) -> None:
        if self.steering_track_width is None:
            object.__setattr__(self, "steering_track_width", self.track_width)
        _check_positive(self, "wheel_radius", "wheelbase", "track_width", "steering_track_width")

    def _phi(self, U):
        L, b = self.wheelbase, 0.5 * self.steering_track_width
        out, grad = [], []
        for delta, side in ((U[:, 2], 1.0), (U[:, 3], -1.0)):
            y, x = L * np.sin(delta), L * np.cos(delta) + side * b * np.sin(delta)
            phi = np.arctan2(y, x)
            out.append(phi - np.pi * np.rint(phi / np.pi))  # tan-preserving fold (arctan)
            grad.append(L * L / (x * x + y * y))
        return 0.5 * (out[0] + out[1]), 0.5 * np.stack(grad, axis=1)

    def inverse(self, twist) -> np.ndarray:
        """``(rear_left, rear_right, steer_left, steer_right)``, steering in ``(-pi/2, pi/2]``.

        Each front wheel's angle follows Ackermann geometry, ``tan(delta) = omega L /
        (v_x -+ omega b)``. Raises ``ValueError`` for ``v_y != 0`` and for turning on the spot
        (``v_x = 0``), where the two virtual angles are ``+pi/2`` and ``-pi/2`` and their
        mean (ros2_controllers' fusion) loses the rotation.
        """
        T, single = _twists(twist, "CarAckermann.inverse")
        left, right = self._rear_inverse(T)
        w, vx = T[:, 0], T[:, 1]
        scale = 1.0 + np.linalg.norm(T, axis=1)
        _unreachable(
            (np.abs(vx) <= _REACH_TOL * scale) & (np.abs(w) > _REACH_TOL * scale),
            np.abs(w),
            "CarAckermann",
            "turning on the spot needs both virtual steering angles at +-pi/2",
        )
        L, b = self.wheelbase, 0.5 * self.steering_track_width
        _, d_l = _steered_wheel_inverse(vx - w * b, w * L)
        _, d_r = _steered_wheel_inverse(vx + w * b, w * L)
        return _out(np.stack([left, right, d_l, d_r], axis=1), single)
