"""Integrators of one step's body twist: :func:`body_increment` (the relative pose and its
Jacobian, ``euler``, ``rk2``, ``exact``, ``euler_end``), :func:`integrate` (a world pose moved by
a twist) and the vectorised chords and cumulative poses :func:`odofuse.motion.dead_reckon`
uses."""

from __future__ import annotations

import numpy as np

from odofuse import se2
from odofuse.declarations import INTEGRATORS


def body_increment(twist, integrator: str = "exact", jacobian: bool = True):
    """Relative pose moved by one step of a body twist, and its Jacobian.

    Parameters
    ----------
    twist : array_like, shape (..., 3)
        ``[omega, v_x, v_y]`` over the step (rad, m, m).
    integrator : {"euler", "rk2", "exact", "euler_end"}
    jacobian : bool
        Also compute the Jacobian (skip it on pose-only paths).

    Returns
    -------
    delta : ndarray, shape (..., 3)
        ``[dx, dy, dtheta]`` in the body frame at the step start.
    J_delta_twist : ndarray, shape (..., 3, 3), or None when ``jacobian`` is false
    """
    tw = np.asarray(twist, dtype=float)
    if integrator == "exact":
        return se2.exp(tw), (se2.J_exp(tw) if jacobian else None)
    w, vx, vy = tw[..., 0], tw[..., 1], tw[..., 2]
    if integrator == "euler" and not jacobian:
        return np.stack([vx, vy, w], -1), None
    if integrator in ("rk2", "euler_end"):
        # Rotated by the mid-step (rk2) or the end-of-step (euler_end) heading change.
        f = 0.5 if integrator == "rk2" else 1.0
        c, s = np.cos(f * w), np.sin(f * w)
        delta = np.stack([c * vx - s * vy, s * vx + c * vy, w], -1)
        if not jacobian:
            return delta, None
    J = np.zeros(tw.shape[:-1] + (3, 3))
    J[..., 2, 0] = 1.0
    if integrator == "euler":
        J[..., 0, 1] = 1.0
        J[..., 1, 2] = 1.0
        return np.stack([vx, vy, w], -1), J
    if integrator in ("rk2", "euler_end"):
        J[..., 0, 0] = f * (-s * vx - c * vy)
        J[..., 1, 0] = f * (c * vx - s * vy)
        J[..., 0, 1], J[..., 0, 2] = c, -s
        J[..., 1, 1], J[..., 1, 2] = s, c
        return delta, J
    raise ValueError(f"unknown integrator '{integrator}'; use one of {', '.join(INTEGRATORS)}")


def integrate(pose, twist, integrator: str = "exact"):
    """One integration step in the world frame.

    Returns
    -------
    pose_new : ndarray, shape (..., 3)
    F_p : ndarray, shape (..., 3, 3)
        Jacobian w.r.t. the pose (Siegwart's ``F_p``).
    J_pose_twist : ndarray, shape (..., 3, 3)
        Jacobian of the new pose w.r.t. the twist ``[omega, v_x, v_y]``.
    """
    delta, J_delta_twist = body_increment(twist, integrator)
    F_p, J_b = se2.J_compose(pose, delta)
    return se2.compose(pose, delta), F_p, J_b @ J_delta_twist


def _dsinc_half(w):
    """d/dw of sinc(w/2) = sin(w/2)/(w/2); Taylor series where the closed form cancels."""
    h = 0.5 * w
    small = np.abs(h) < 0.05
    hs = np.where(small, 1.0, h)
    closed = (hs * np.cos(hs) - np.sin(hs)) / (hs * hs)
    h2 = h * h
    series = h * (-1.0 / 3.0 + h2 * (1.0 / 30.0 + h2 * (-1.0 / 840.0 + h2 / 45360.0)))
    return 0.5 * np.where(small, series, closed)


def _chord(theta_start, twist, integrator: str):
    """Each step's displacement in complex form, ``z_k = g(w) (v_x + i v_y) e^{i phi_k}``.

    ``exact`` has ``g = sinc(w/2)`` and ``phi_k = theta_k + w/2`` (the chord of the arc), ``rk2``
    ``g = 1`` at the same mid angle, ``euler`` ``g = 1`` at ``phi_k = theta_k``: the same
    increment as :func:`body_increment` composed with the pose, with three transcendental
    evaluations per step instead of six.

    Returns ``zr, zi`` (the rotated velocity ``(v_x + i v_y) e^{i phi}``), ``c, s``
    (``cos phi``, ``sin phi``) and ``g`` (None unless ``exact``).
    """
    w, vx, vy = twist[:, 0], twist[:, 1], twist[:, 2]
    half = 0.5 * w
    if integrator == "euler":
        phi = theta_start
    elif integrator == "euler_end":
        phi = theta_start + w
    else:
        phi = theta_start + half
    c, s = np.cos(phi), np.sin(phi)
    g = None
    if integrator == "exact":
        g = np.divide(np.sin(half), half, out=np.ones_like(half), where=half != 0.0)
    return c * vx - s * vy, s * vx + c * vy, c, s, g


def _cumulative_poses(pose0, twist, integrator: str):
    """Poses after each step of ``twist`` ``(N, 3)`` (N+1, 3), and the step-start headings.

    Each running sum starts from the initial value, so it adds in the same order as the
    step-by-step loop (``x_{k+1} = x_k + dx_k``).
    """
    n = twist.shape[0]
    theta = np.empty(n + 1)
    theta[0] = pose0[2]
    theta[1:] = twist[:, 0]
    np.cumsum(theta, out=theta)
    zr, zi, _, _, g = _chord(theta[:-1], twist, integrator)
    if g is not None:
        zr *= g
        zi *= g
    poses = np.empty((n + 1, 3))
    for axis, step in ((0, zr), (1, zi)):
        column = np.empty(n + 1)
        column[0] = pose0[axis]
        column[1:] = step
        np.cumsum(column, out=poses[:, axis])
    poses[:, 2] = se2.wrap(theta)
    return poses, theta[:-1]
