"""SE(2) algebra on ``[x, y, theta]`` poses, vectorised over leading axes.

The head-to-tail (compound) operator of ``002_88fc37db58155723.txt``::

    a (+) b = [x_a + x_b cos th_a - y_b sin th_a,
               y_a + x_b sin th_a + y_b cos th_a,
               th_a + th_b]

and the exponential of a planar body twist (Modern Robotics eqs. 13.35-13.36,
``000_96a7e9c96987202e.txt``). Twists use the Modern Robotics order ``[omega, v_x, v_y]``;
relative poses use the pose order ``[dx, dy, dtheta]`` like ``gtsam.Pose2``.

Every function accepts a single ``(3,)`` array or a batch ``(..., 3)`` and returns new arrays.
"""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * np.pi

# Below this |omega| the closed forms of the exp Jacobian lose digits to cancellation
# ((w cos w - sin w) / w^2 has relative error ~ eps / w^2); the Taylor series is exact to
# double precision there (first omitted terms ~ w^9 / 4e6 and w^10 / 4e8).
_SERIES_BELOW = 5e-2


def wrap(angle):
    """Wrap angles (rad) to ``[-pi, pi)``."""
    return (np.asarray(angle, dtype=float) + np.pi) % TWO_PI - np.pi


def wrap_angle(angle: float) -> float:
    """:func:`wrap` of one angle as a Python float: the same three operations (Python's float
    ``%`` is numpy's floored remainder), a tenth of the time (the filters' per-step calls)."""
    return (float(angle) + math.pi) % TWO_PI - math.pi


def rot(theta) -> np.ndarray:
    """2x2 rotation matrices ``R(theta)``, shape ``(..., 2, 2)``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def compose(a, b) -> np.ndarray:
    """Head-to-tail composition ``a (+) b`` (002 source), shape ``(..., 3)``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            wrap(a[..., 2] + b[..., 2]),
        ],
        -1,
    )


def J_compose(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``compose(a, b)`` w.r.t. ``a`` and ``b`` (additive world coordinates).

    Returns
    -------
    J_a, J_b : ndarray, shape (..., 3, 3)
        ``J_a = [[1, 0, -dy_w], [0, 1, dx_w], [0, 0, 1]]`` with ``(dx_w, dy_w) = R(th_a) b_xy``
        (Siegwart's F_p); ``J_b = blockdiag(R(th_a), 1)``.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    shape = np.broadcast_shapes(a.shape, b.shape)[:-1]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dxw = c * b[..., 0] - s * b[..., 1]
    dyw = s * b[..., 0] + c * b[..., 1]
    J_a = np.broadcast_to(np.eye(3), shape + (3, 3)).copy()
    J_a[..., 0, 2] = -dyw
    J_a[..., 1, 2] = dxw
    J_b = np.zeros(shape + (3, 3))
    J_b[..., :2, :2] = rot(a[..., 2])
    J_b[..., 2, 2] = 1.0
    return J_a, J_b


def inverse(a) -> np.ndarray:
    """Inverse pose: ``compose(a, inverse(a)) == 0``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], wrap(-a[..., 2])], -1
    )


def between(a, b) -> np.ndarray:
    """Relative pose of ``b`` seen from ``a``: ``inverse(a) (+) b`` (like ``Pose2.between``)."""
    return compose(inverse(a), b)


def _exp_coefficients(w, derivatives: bool = False):
    """``A = sin(w)/w``, ``B = (1 - cos w)/w`` and optionally ``dA/dw``, ``dB/dw``.

    A and B come from the half angle (``A = sinc(w/2) cos(w/2)``, ``B = sinc(w/2) sin(w/2)``),
    which avoids the cancellation of ``1 - cos w`` for small ``w``. The derivatives use their
    Taylor series below ``_SERIES_BELOW``.
    """
    w = np.asarray(w, dtype=float)
    half = 0.5 * w
    sh, ch = np.sin(half), np.cos(half)
    zero = w == 0.0
    sinc_half = np.where(zero, 1.0, sh / np.where(zero, 1.0, half))
    A, B = sinc_half * ch, sinc_half * sh
    if not derivatives:
        return A, B
    small = np.abs(w) < _SERIES_BELOW
    ws = np.where(small, 1.0, w)
    inv2 = 1.0 / (ws * ws)
    s, omc = 2.0 * sh * ch, 2.0 * sh * sh  # sin w, 1 - cos w
    w2 = w * w
    dA_series = w * (-1.0 / 3.0 + w2 * (1.0 / 30.0 + w2 * (-1.0 / 840.0 + w2 / 45360.0)))
    dB_series = 0.5 + w2 * (-1.0 / 8.0 + w2 * (1.0 / 144.0 + w2 * (-1.0 / 5760.0 + w2 / 403200.0)))
    dA = np.where(small, dA_series, (ws * (1.0 - omc) - s) * inv2)
    dB = np.where(small, dB_series, (ws * s - omc) * inv2)
    return A, B, dA, dB


def exp(twist) -> np.ndarray:
    """Relative pose reached by a constant body twist over unit time (MR eq. 13.35).

    Parameters
    ----------
    twist : array_like, shape (..., 3)
        ``[omega, v_x, v_y]`` integrated over Delta t = 1 (rad, m, m).

    Returns
    -------
    ndarray, shape (..., 3)
        ``[dx, dy, dtheta]`` in the start body frame. Stable at and near ``omega = 0``.
    """
    tw = np.asarray(twist, dtype=float)
    w, vx, vy = tw[..., 0], tw[..., 1], tw[..., 2]
    A, B = _exp_coefficients(w)
    return np.stack([A * vx - B * vy, B * vx + A * vy, w], -1)


def J_exp(twist) -> np.ndarray:
    """Jacobian of :func:`exp`: rows ``[dx, dy, dtheta]``, columns ``[omega, v_x, v_y]``."""
    tw = np.asarray(twist, dtype=float)
    w, vx, vy = tw[..., 0], tw[..., 1], tw[..., 2]
    A, B, dA, dB = _exp_coefficients(w, derivatives=True)
    J = np.zeros(tw.shape[:-1] + (3, 3))
    J[..., 0, 0] = dA * vx - dB * vy
    J[..., 0, 1] = A
    J[..., 0, 2] = -B
    J[..., 1, 0] = dB * vx + dA * vy
    J[..., 1, 1] = B
    J[..., 1, 2] = A
    J[..., 2, 0] = 1.0
    return J


def log(delta) -> np.ndarray:
    """Inverse of :func:`exp`: the twist ``[omega, v_x, v_y]`` that reaches ``delta``.

    ``delta[..., 2]`` must lie in ``(-2 pi, 2 pi)`` (it is used as given, not wrapped).
    """
    d = np.asarray(delta, dtype=float)
    w = d[..., 2]
    A, B = _exp_coefficients(w)
    den = A**2 + B**2  # = sinc(w/2)^2 > 0 for |w| < 2 pi
    vx = (A * d[..., 0] + B * d[..., 1]) / den
    vy = (-B * d[..., 0] + A * d[..., 1]) / den
    return np.stack([w, vx, vy], -1)


def icr_construction(twist) -> np.ndarray:
    """Relative pose by the centre-of-rotation construction of ``001_8aaeb0868ac55f59.txt``.

    ``T_bb' = T_bs T_ss' T_s'b'`` with the centre of rotation ``(x_s, y_s) = (-v_y, v_x)/omega``.
    Only defined for ``omega != 0``; used to check :func:`exp` independently.
    """
    tw = np.asarray(twist, dtype=float)
    w, vx, vy = tw[..., 0], tw[..., 1], tw[..., 2]
    zero = np.zeros_like(w)
    centre = np.stack([-vy / w, vx / w, zero], -1)
    spin = np.stack([zero, zero, w], -1)
    return compose(compose(centre, spin), -centre)


def to_matrix(pose) -> np.ndarray:
    """Homogeneous 3x3 matrices of poses, shape ``(..., 3, 3)``."""
    p = np.asarray(pose, dtype=float)
    T = np.zeros(p.shape[:-1] + (3, 3))
    T[..., :2, :2] = rot(p[..., 2])
    T[..., :2, 2] = p[..., :2]
    T[..., 2, 2] = 1.0
    return T


def from_matrix(T) -> np.ndarray:
    """Pose ``[x, y, theta]`` of homogeneous 3x3 matrices."""
    T = np.asarray(T, dtype=float)
    return np.stack([T[..., 0, 2], T[..., 1, 2], np.arctan2(T[..., 1, 0], T[..., 0, 0])], -1)


def _frame_jacobian(pose) -> np.ndarray:
    """``d(world perturbation)/d(body perturbation)`` at ``pose``: ``blockdiag(R(theta), 1)``.

    A pose perturbed on the right, ``pose * Exp(xi)``, moves to first order by
    ``[R(theta) xi_xy, xi_theta]`` in additive world coordinates.
    """
    p = np.asarray(pose, dtype=float)
    J = np.zeros(p.shape[:-1] + (3, 3))
    J[..., :2, :2] = rot(p[..., 2])
    J[..., 2, 2] = 1.0
    return J


def cov_world_to_body(pose, P) -> np.ndarray:
    """World-frame covariance over ``[x, y, theta]`` -> GTSAM ``Pose2`` tangent (body) covariance.

    This and :func:`cov_body_to_world` are the only places the two conventions meet.
    """
    J = _frame_jacobian(pose)
    return np.swapaxes(J, -1, -2) @ np.asarray(P, dtype=float) @ J


def cov_body_to_world(pose, P) -> np.ndarray:
    """GTSAM ``Pose2`` tangent (body) covariance -> world covariance over ``[x, y, theta]``."""
    J = _frame_jacobian(pose)
    return J @ np.asarray(P, dtype=float) @ np.swapaxes(J, -1, -2)
