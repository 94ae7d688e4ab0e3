"""The motion model every back end shares: :class:`MotionModel` (drive + error model +
integrator), vectorised :func:`dead_reckon` with covariances, :func:`side_outliers` (wheels
that disagree with their side mates) and :func:`motion_model_from_config`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odofuse import se2
from odofuse.declarations import INTEGRATORS
from odofuse.errors import check_array
from odofuse.motion.integrators import (
    _chord,
    _cumulative_poses,
    _dsinc_half,
    body_increment,
)
from odofuse.motion.noise import OdometryErrorModel, error_model_from_config


@dataclass(frozen=True)
class MotionModel:
    """Drive model + error model + integrator: the single motion model of every back end."""

    drive: object
    errors: OdometryErrorModel
    integrator: str = "exact"

    def __post_init__(self) -> None:
        if self.integrator not in INTEGRATORS:
            raise ValueError(
                f"unknown integrator '{self.integrator}'; use one of {', '.join(INTEGRATORS)}"
            )
        n = len(self.drive.input_names)
        if len(self.errors.k) != n or len(self.errors.floor) != n:
            raise ValueError(
                f"error model needs {n} k and floor values for inputs {self.drive.input_names}"
            )

    def increment(self, u) -> tuple[np.ndarray, np.ndarray]:
        """Body-frame relative pose of one step and its Jacobian ``J_delta_u`` ``(..., 3, n)``."""
        delta, J_delta_twist = body_increment(self.drive.twist(u), self.integrator)
        return delta, J_delta_twist @ self.drive.J_twist_u(u)

    def input_cov(self, u) -> np.ndarray:
        """``Sigma_u``: diagonal covariance of the inputs of one step, shape ``(n, n)``."""
        return np.diag(self.errors.variances(self.drive, u))

    def predict(self, pose, P, u):
        """One prediction step with covariance propagation.

        Returns
        -------
        pose_new : ndarray (3,)
        P_new : ndarray (3, 3)
            ``F_p P F_p^T + F_u Sigma_u F_u^T`` (world frame).
        F_p : ndarray (3, 3)
        F_u : ndarray (3, n)
        """
        delta, J_delta_u = self.increment(u)
        F_p, J_b = se2.J_compose(pose, delta)
        F_u = J_b @ J_delta_u
        var = self.errors.variances(self.drive, u)
        P_new = F_p @ P @ F_p.T + (F_u * var) @ F_u.T
        return se2.compose(pose, delta), 0.5 * (P_new + P_new.T), F_p, F_u

    def relative(self, U) -> tuple[np.ndarray, np.ndarray]:
        """Pre-integrate steps ``U`` ``(N, n)`` into one relative pose and its covariance.

        Returns
        -------
        delta : ndarray (3,)
            Relative pose of the last step's end in the first step's start frame.
        cov_body : ndarray (3, 3)
            Its covariance in GTSAM's ``Pose2`` tangent convention (body frame at the end),
            ready for ``BetweenFactorPose2``.
        """
        U = np.atleast_2d(np.asarray(U, dtype=float))
        poses, covs = dead_reckon(self, np.zeros(3), np.zeros((3, 3)), U)
        return poses[-1], se2.cov_world_to_body(poses[-1], covs[-1])


def _process_noise(model: MotionModel, theta_start, twist, U) -> tuple[np.ndarray, ...]:
    """Unique entries ``(q00, q01, q02, q11, q12, q22)`` of each step's world-frame process
    noise ``Q_k = F_u Sigma_u F_u^T``, each ``(N,)``.

    ``F_u = J_pose_twist J_twist_u`` with the rows of ``J_pose_twist`` taken from the complex
    form of :func:`_chord`: ``dz/dv_x = g e^{i phi}``, ``dz/dv_y = i g e^{i phi}`` and
    ``dz/dw = (v_x + i v_y) e^{i phi} (g' + i g dphi/dw)``; the theta row is ``(1, 0, 0)``.
    Plain 1-D arithmetic: numpy's batched 3x3 matmuls are several times slower here.
    """
    zr, zi, c, s, g = _chord(theta_start, twist, model.integrator)
    if model.integrator == "exact":
        a, b = _dsinc_half(twist[:, 0]), 0.5 * g
        jw0, jw1 = zr * a - zi * b, zr * b + zi * a
        c, s = g * c, g * s
    elif model.integrator == "rk2":
        jw0, jw1 = -0.5 * zi, 0.5 * zr
    elif model.integrator == "euler_end":
        jw0, jw1 = -zi, zr
    else:
        jw0 = jw1 = np.zeros_like(zr)
    J_tu = model.drive.J_twist_u(U)
    Tw, Tx, Ty = J_tu[:, 0, :], J_tu[:, 1, :], J_tu[:, 2, :]
    F0 = jw0[:, None] * Tw + c[:, None] * Tx - s[:, None] * Ty
    F1 = jw1[:, None] * Tw + s[:, None] * Tx + c[:, None] * Ty
    var = model.errors.variances(model.drive, U)
    V0, V1, V2 = F0 * var, F1 * var, Tw * var

    def dot(x, y):
        return np.einsum("nk,nk->n", x, y)

    return dot(V0, F0), dot(V0, F1), dot(V0, Tw), dot(V1, F1), dot(V1, Tw), dot(V2, Tw)


# Block length of the closed-form covariance recursion. Within a block, positions are taken
# relative to the block's first pose so the prefix sums stay small and cancellation is bounded.
_COV_BLOCK = 8192


def dead_reckon(model: MotionModel, pose0, P0, U, with_cov: bool = True):
    """Dead reckoning over a whole array of steps, vectorised.

    Because every step's ``F_p = I + E(d_k)`` (``E`` adds the world displacement ``d_k`` to the
    theta column) and ``E(a) E(b) = 0``, the product of the ``F_p`` from step ``j`` to ``n`` is
    ``I + E(p_n - p_j)``. The covariance recursion
    ``P_n = Phi(n, m) P_m Phi(n, m)^T + sum_j Phi(n, j+1) Q_j Phi(n, j+1)^T`` then becomes
    prefix sums over each block. The result equals the step-by-step ``MotionModel.predict``
    loop to rounding error.

    Parameters
    ----------
    model : MotionModel
    pose0 : array_like (3,)
    P0 : array_like (3, 3)
    U : array_like (N, n)
        Drive inputs of each step.
    with_cov : bool
        Also propagate covariances.

    Returns
    -------
    poses : ndarray (N+1, 3)
        The initial pose and the pose after each step.
    covs : ndarray (N+1, 3, 3) or None

    Raises
    ------
    InputError
        An argument of another shape (``U`` must be ``(N, n)``, one column per drive input,
        never reshaped), a non-numeric dtype or a non-finite value.
    """
    names = tuple(model.drive.input_names)
    pose0 = check_array(pose0, "pose0", (3,), "(3,): x, y, theta")
    if with_cov:  # P0 is not read without covariances (callers pass None)
        P0 = check_array(P0, "P0", (3, 3))
    U = check_array(
        U,
        "U",
        (None, len(names)),
        f"(N, {len(names)}): one row per step, columns {', '.join(names)}",
    )
    twist = model.drive.twist(U)
    poses, theta_start = _cumulative_poses(pose0, twist, model.integrator)
    if not with_cov:
        return poses, None
    n_steps = U.shape[0]
    covs = np.empty((n_steps + 1, 3, 3))
    P_m = 0.5 * (np.asarray(P0, dtype=float) + np.asarray(P0, dtype=float).T)
    covs[0] = P_m
    cs = np.cumsum
    # Blocks also keep every temporary small enough to stay in cache.
    for m in range(0, n_steps, _COV_BLOCK):
        stop = min(m + _COV_BLOCK, n_steps)
        q00, q01, q02, q11, q12, q22 = _process_noise(
            model, theta_start[m:stop], twist[m:stop], U[m:stop]
        )
        # f_j = L(p_{j+1} - p_m) = (-(y - y_m), x - x_m); it is also e_n for the end pose n.
        e0 = poses[m, 1] - poses[m + 1 : stop + 1, 1]
        e1 = poses[m + 1 : stop + 1, 0] - poses[m, 0]
        # sum_j Phi(n, j+1) Q_j Phi(n, j+1)^T with a_j = e_n - f_j, entry by entry:
        # Q + a q^T + q a^T + q22 a a^T, q = Q[:, 2] and a_2 = 0.
        S22, S02, S12 = cs(q22), cs(q02), cs(q12)
        F0, F1 = cs(e0 * q22), cs(e1 * q22)
        P22 = S22 + P_m[2, 2]
        P02 = S02 + e0 * S22 - F0
        P12 = S12 + e1 * S22 - F1
        P00 = (
            cs(q00)
            + 2.0 * (e0 * S02 - cs(e0 * q02))
            + e0 * (e0 * S22 - 2.0 * F0)
            + cs(e0 * e0 * q22)
        )
        P11 = (
            cs(q11)
            + 2.0 * (e1 * S12 - cs(e1 * q12))
            + e1 * (e1 * S22 - 2.0 * F1)
            + cs(e1 * e1 * q22)
        )
        P01 = (
            cs(q01)
            + e0 * S12
            - cs(e0 * q12)
            + e1 * S02
            - cs(e1 * q02)
            + e0 * e1 * S22
            - e0 * F1
            - e1 * F0
            + cs(e0 * e1 * q22)
        )
        # + Phi(n, m) P_m Phi(n, m)^T with a = e_n
        p02, p12, p22 = P_m[0, 2], P_m[1, 2], P_m[2, 2]
        P00 += P_m[0, 0] + e0 * (2.0 * p02 + e0 * p22)
        P11 += P_m[1, 1] + e1 * (2.0 * p12 + e1 * p22)
        P01 += P_m[0, 1] + e0 * p12 + e1 * p02 + e0 * e1 * p22
        P02 += p02 + e0 * p22
        P12 += p12 + e1 * p22
        block = covs[m + 1 : stop + 1]
        block[:, 0, 0], block[:, 1, 1], block[:, 2, 2] = P00, P11, P22
        block[:, 0, 1] = block[:, 1, 0] = P01
        block[:, 0, 2] = block[:, 2, 0] = P02
        block[:, 1, 2] = block[:, 2, 1] = P12
        P_m = covs[stop]
    return poses, covs


def side_outliers(model: MotionModel, U, n_sigma: float = 3.0) -> np.ndarray:
    """Wheels that disagree with their side mates by more than their noise, per step.

    For a drive with ``input_groups`` (``wheels_per_side > 1``), every wheel of a group measures
    the same side travel. Wheel ``i``'s travel ``s_i = scale_i u_i`` (m) is compared with the
    median ``m`` of its group; it is flagged when ``|s_i - m| > n_sigma sigma_i`` with
    ``sigma_i^2 = scale_i^2 var_i + min_j scale_j^2 var_j`` (its own error-model variance plus
    the smallest of the group's, a lower bound of the median's; conservative by design, so a
    noisy but healthy wheel is rarely flagged). With two wheels per side the median is the
    mean and both wheels of a disagreeing pair are flagged: two readings cannot say which
    one slipped.

    Parameters
    ----------
    model : MotionModel
    U : array_like, shape (N, n)
        Drive inputs per step.
    n_sigma : float
        Threshold in standard deviations.

    Returns
    -------
    ndarray of bool, shape (N, n)
        False everywhere for drives without ``input_groups``.
    """
    U = np.atleast_2d(np.asarray(U, dtype=float))
    flagged = np.zeros(U.shape, dtype=bool)
    groups = [g for g in getattr(model.drive, "input_groups", ()) if len(g) > 1]
    if not groups:
        return flagged
    scale = np.asarray(model.drive.travel_scale(), dtype=float)
    travel = U * scale
    var = model.errors.variances(model.drive, U) * scale**2
    for group in groups:
        g = list(group)
        med = np.median(travel[:, g], axis=1, keepdims=True)
        bound = var[:, g] + np.min(var[:, g], axis=1, keepdims=True)
        flagged[:, g] = np.abs(travel[:, g] - med) > n_sigma * np.sqrt(bound)
    return flagged


GEOMETRY_EXCLUDE = ("drive", "encoder")


def motion_model_from_config(config) -> MotionModel:
    """The run's :class:`MotionModel` from ``config.robot`` and ``config.motion``."""
    from odofuse.drives import make_drive

    robot = dict(config.robot)
    geometry = {k: v for k, v in robot.items() if k not in GEOMETRY_EXCLUDE}
    drive = make_drive(robot["drive"], **geometry)
    motion = config.motion
    return MotionModel(drive, error_model_from_config(drive, motion), motion.integrator)


def linear_terms(model: MotionModel):
    """``(M, K, floor, rate)`` of a drive with ``twist = M u`` (``drive.matrix()``), whose
    input variances are ``var = K |u| + floor + rate dt``; None for other drives.

    ``K = (diag(k) + C) diag(scale) / scale_i^2`` on wheel rows (0 on steering rows), the
    :meth:`OdometryErrorModel.variances` without its quadratic term (callers check ``quadratic``
    and compare with :meth:`~OdometryErrorModel.variances` before relying on it).

    Returns
    -------
    M : ndarray (3, n); K : ndarray (n, n); floor : ndarray (n,); rate : ndarray (n,), per s
    """
    drive = model.drive
    if not hasattr(drive, "matrix"):
        return None
    M = np.asarray(drive.matrix(), dtype=float)
    scale = np.abs(np.asarray(drive.travel_scale(), dtype=float))
    safe = np.where(scale > 0, scale, 1.0)
    K = np.diag(np.asarray(model.errors.k, dtype=float))
    if model.errors.cross is not None:
        K = K + np.asarray(model.errors.cross, dtype=float)
    K = np.where((scale > 0)[:, None], K * scale[None, :] / (safe**2)[:, None], 0.0)
    floor = np.asarray(model.errors.floor, dtype=float)
    rate = model.errors.rate
    rate = np.zeros(len(floor)) if rate is None else np.asarray(rate, dtype=float)
    return M, K, floor, rate
