"""Motion models: integrators, the odometry error model and dead reckoning.

One :class:`MotionModel` (drive + error model + integrator) serves every back end: the EKF/UKF
prediction, the particle filter's sampling and the factor graph's odometry factors all call it.

Integrators (Politecnico slides ``003_73fced8ec7c15fe5.txt``, Modern Robotics 13.35-13.36 in
``000_96a7e9c96987202e.txt``), for a step's body twist ``[omega, v_x, v_y]`` (Delta t = 1):

* ``euler``: the body moves by ``[v_x, v_y]`` along the heading at the step start;
* ``rk2``: the same along the mid-step heading ``theta + omega/2`` (Siegwart's model in
  ``004_f4547100a083f338.txt`` is this one with ``v_y = 0``);
* ``exact``: the twist exponential (arc of a circle about the ICR);
* ``euler_end``: the body moves by ``[v_x, v_y]`` along the heading at the step *end*
  (``theta + omega``): heading first, then position, as ros2_controllers' mecanum drive
  controller integrates (``mecanum_drive_controller/src/odometry.cpp``, ``Odometry::update``).

Error model (Siegwart & Nourbakhsh ch. 5): each wheel's travel ``ds_i`` has variance
``k_i |ds_i|`` (m^2 per m), uncorrelated between wheels; steering inputs have a constant
variance; every input may add a per-step and a per-second floor. Increment and twist inputs
add a heading variance per metre travelled (:func:`implied_k_theta_ds`), so driving straight
never claims a perfect heading. ``Sigma_p' = F_p Sigma_p F_p^T + F_u Sigma_u F_u^T``.
Velocity inputs (the ``twist`` and ``increments`` drives) may add Thrun's quadratic
velocity-model terms (``OdometryErrorModel.quadratic``).
Redundant wheels (``wheels_per_side``) are checked against their side mates by
:func:`side_outliers`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odofuse import se2
from odofuse.declarations import INTEGRATORS, MotionOptions
from odofuse.options import coerce


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


@dataclass(frozen=True)
class OdometryErrorModel:
    """Per-input variances of one odometry step (Siegwart & Nourbakhsh ch. 5, generalised).

    ``var(u_i) = (k_i |travel_i| + sum_j C_ij |travel_j|) / scale_i^2 + floor_i + rate_i dt``
    for wheel inputs (``travel`` in metres, ``scale`` = metres per input unit, the wheel radius
    for wheel angles), and ``floor_i + rate_i dt`` alone for inputs with zero scale (steering
    angles). ``C`` (``cross``) carries the distance-driven heading variance of the increment
    and twist drives (``motion.k_theta_ds``, derived in ``docs/motion.md``). With ``quadratic``
    (an ``(n, n)`` matrix ``Q``) each variance also gets ``sum_j Q_ij u_j^2``: Thrun, Burgard &
    Fox's velocity motion model (Probabilistic Robotics, Table 5.3, alphas on variances) for
    the ``twist`` and ``increments`` drives, whose inputs are ``v dt`` and ``w dt``.

    Parameters
    ----------
    k : tuple of float
        ``k_i`` in m^2 per metre travelled, one per drive input (0 for steering inputs).
    floor : tuple of float
        Constant variance per input and step, in the input's units squared.
    quadratic : tuple of tuple of float, optional
        ``Q`` (n x n), dimensionless; default none.
    cross : tuple of tuple of float, optional
        ``C`` (n x n, zero diagonal), m^2 per metre of input ``j``'s travel; default none.
    rate : tuple of float, optional
        Variance per second of each input (input units squared per s); used where the step's
        duration ``dt`` is known (the filters); default none.
    """

    k: tuple[float, ...]
    floor: tuple[float, ...]
    quadratic: tuple[tuple[float, ...], ...] | None = None
    cross: tuple[tuple[float, ...], ...] | None = None
    rate: tuple[float, ...] | None = None

    def variances(self, drive, u, dt: float | None = None) -> np.ndarray:
        """Input variances, shape ``(..., n)``; ``dt`` (s) adds the per-time ``rate`` term."""
        scale = np.asarray(drive.travel_scale(), dtype=float)
        travel = np.abs(drive.travel(u))
        safe = np.where(scale > 0, scale, 1.0)
        lin = np.asarray(self.k) * travel
        if self.cross is not None:
            lin = lin + travel @ np.asarray(self.cross).T
        wheel = np.where(scale > 0, lin / safe**2, 0.0)
        var = wheel + np.asarray(self.floor)
        if self.quadratic is not None:
            var = var + np.square(np.asarray(u, dtype=float)) @ np.asarray(self.quadratic).T
        if self.rate is not None and dt is not None:
            var = var + np.asarray(self.rate) * max(float(dt), 0.0)
        return var


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
    """
    pose0 = np.asarray(pose0, dtype=float)
    U = np.asarray(U, dtype=float).reshape(-1, len(model.drive.input_names))
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


def implied_k_theta_ds(k_ds: float, k_dtheta: float) -> float:
    """Heading variance per metre of the two-wheel robot with the same increment ``k``.

    A differential robot of track ``b`` with ``var(ds_w) = k_w |ds_w|`` per wheel (Siegwart &
    Nourbakhsh ch. 5, ``004_f4547100a083f338.txt``) has ``ds = (ds_r + ds_l)/2``,
    ``dtheta = (ds_r - ds_l)/b`` and hence ``var(ds) = k_w (|ds_r| + |ds_l|)/4``,
    ``var(dtheta) = k_w (|ds_r| + |ds_l|)/b^2`` with ``|ds_r| + |ds_l| = max(2|ds|, b|dtheta|)``.
    Straight (``dtheta = 0``) that is ``k_ds = k_w/2``; turning on the spot
    ``k_dtheta = k_w/b``; so ``b = 2 k_ds/k_dtheta`` and the straight-line heading variance per
    metre is ``2 k_w/b^2 = k_dtheta^2/k_ds``. The sum ``k_theta_ds |ds| + k_dtheta |dtheta|``
    bounds the max from above and equals it on both limits.

    Parameters
    ----------
    k_ds : float
        m^2 per m.
    k_dtheta : float
        rad^2 per rad.

    Returns
    -------
    float
        rad^2 per m; 0 when ``k_dtheta`` is 0.
    """
    if k_dtheta == 0.0:
        return 0.0
    if k_ds <= 0.0:
        raise ValueError("motion.k_theta_ds: set it explicitly when k[0] (ds) is 0")
    return k_dtheta**2 / k_ds


def error_model_from_config(drive, motion) -> OdometryErrorModel:
    """Build the error model from the ``motion`` block (:class:`MotionOptions` or a mapping).

    Keys: ``k_r``/``k_l`` (differential and skid-steer: right/left wheel), or ``k`` (a number
    for every wheel input, or a list per input), ``var_floor`` (a number or a list per input,
    per step), ``var_rate`` (per second), ``steer_sigma`` (rad, steering inputs),
    ``k_theta_ds`` (increments and twist: heading variance per metre travelled, default
    :func:`implied_k_theta_ds`), ``alphas`` (Thrun's ``[a1, a2, a3, a4]`` on variances, for
    drives with ``quadratic_noise``: ``twist``, ``increments``); defaults in
    :class:`odofuse.declarations.MotionOptions`. ``k_l``/``k_r`` apply to every wheel of that
    side (``wheels_per_side``).
    """
    motion = coerce(MotionOptions, motion, "motion")
    names = tuple(drive.input_names)
    n = len(names)
    scale = np.asarray(drive.travel_scale(), dtype=float)
    k = np.broadcast_to(np.asarray(motion.k, dtype=float), (n,)).copy()
    if motion.k_r is not None or motion.k_l is not None:
        sides = np.asarray(getattr(drive, "sides", ()))
        if sides.shape != (n,):
            raise ValueError(f"k_r/k_l apply to left/right wheels; this drive's inputs are {names}")
        for side, value in (("left", motion.k_l), ("right", motion.k_r)):
            if value is not None:
                k[sides == side] = float(value)
    floor = np.broadcast_to(np.asarray(motion.var_floor, dtype=float), (n,)).copy()
    rate = np.broadcast_to(np.asarray(motion.var_rate, dtype=float), (n,)).copy()
    steer_var = float(motion.steer_sigma) ** 2
    floor = np.where(scale > 0, floor, floor + steer_var)
    k = np.where(scale > 0, k, 0.0)
    cross = None
    heading = getattr(drive, "heading_input", None)
    if heading is None:
        if motion.k_theta_ds is not None:
            raise ValueError(
                f"motion.k_theta_ds applies to the increments and twist drives, not "
                f"'{drive.name}' (its heading variance already grows with wheel travel)"
            )
    else:
        trans = tuple(drive.translation_inputs)
        kts = motion.k_theta_ds
        if kts is None:
            kts = implied_k_theta_ds(float(k[trans[0]]), float(k[heading]))
        C = np.zeros((n, n))
        C[heading, list(trans)] = float(kts)
        cross = tuple(map(tuple, C.tolist()))
    quadratic = None
    if motion.alphas is not None:
        if not hasattr(drive, "quadratic_noise"):
            raise ValueError(
                f"motion.alphas (Thrun's velocity model) needs the increments or twist drive, "
                f"not '{drive.name}'"
            )
        quadratic = tuple(map(tuple, np.asarray(drive.quadratic_noise(motion.alphas)).tolist()))
    return OdometryErrorModel(
        tuple(map(float, k)),
        tuple(map(float, floor)),
        quadratic,
        cross,
        tuple(map(float, rate)) if np.any(rate > 0) else None,
    )


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


@dataclass(frozen=True)
class ThrunOdometryModel:
    """Thrun, Burgard & Fox's odometry motion model (Probabilistic Robotics, Table 5.6).

    A relative motion is decomposed into a rotation ``rot1``, a translation ``trans`` and a
    rotation ``rot2``. Convention: the ``alpha`` parameters weight **variances**, as in the
    book and nav2 AMCL (MRPT weights standard deviations instead)::

        var(rot1)  = a1 rot1^2 + a2 trans^2
        var(trans) = a3 trans^2 + a4 (rot1^2 + rot2^2)
        var(rot2)  = a1 rot2^2 + a2 trans^2
    """

    alphas: tuple[float, float, float, float]

    @staticmethod
    def decompose(delta) -> np.ndarray:
        """``[rot1, trans, rot2]`` of body-frame relative poses ``delta`` ``(..., 3)``."""
        d = np.asarray(delta, dtype=float)
        trans = np.hypot(d[..., 0], d[..., 1])
        rot1 = np.where(trans > 0, np.arctan2(d[..., 1], d[..., 0]), 0.0)
        return np.stack([rot1, trans, se2.wrap(d[..., 2] - rot1)], -1)

    @staticmethod
    def recompose(rtr) -> np.ndarray:
        """Inverse of :meth:`decompose`: body-frame relative pose of ``[rot1, trans, rot2]``."""
        r = np.asarray(rtr, dtype=float)
        return np.stack(
            [
                r[..., 1] * np.cos(r[..., 0]),
                r[..., 1] * np.sin(r[..., 0]),
                se2.wrap(r[..., 0] + r[..., 2]),
            ],
            -1,
        )

    def variances(self, rtr) -> np.ndarray:
        """Variances of ``[rot1, trans, rot2]``, shape ``(..., 3)``."""
        a1, a2, a3, a4 = self.alphas
        r = np.asarray(rtr, dtype=float)
        r1, t, r2 = r[..., 0] ** 2, r[..., 1] ** 2, r[..., 2] ** 2
        return np.stack([a1 * r1 + a2 * t, a3 * t + a4 * (r1 + r2), a1 * r2 + a2 * t], -1)

    def sample(self, rng: np.random.Generator, poses, delta) -> np.ndarray:
        """Move each of ``poses`` ``(N, 3)`` by a noisy copy of ``delta`` (one draw each)."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        rtr = self.decompose(delta)
        noisy = rtr + rng.normal(size=poses.shape) * np.sqrt(self.variances(rtr))
        return se2.compose(poses, self.recompose(noisy))

    def covariance(self, pose, P, delta) -> tuple[np.ndarray, np.ndarray]:
        """Linearised propagation: new pose and ``F_p P F_p^T + F_r Sigma_rtr F_r^T``."""
        rtr = self.decompose(delta)
        r1, t, _ = rtr
        a = pose[2] + r1
        F_r = np.array(
            [[-t * np.sin(a), np.cos(a), 0.0], [t * np.cos(a), np.sin(a), 0.0], [1.0, 0.0, 1.0]]
        )
        new = se2.compose(pose, self.recompose(rtr))
        F_p, _ = se2.J_compose(pose, self.recompose(rtr))
        P_new = F_p @ P @ F_p.T + (F_r * self.variances(rtr)) @ F_r.T
        return new, 0.5 * (P_new + P_new.T)
