"""Odometry error models: :class:`OdometryErrorModel` (Siegwart & Nourbakhsh's per-metre
input variances, generalised; built from the ``motion`` block by
:func:`error_model_from_config`, with :func:`implied_k_theta_ds`) and Thrun, Burgard & Fox's
:class:`ThrunOdometryModel` (rot1-trans-rot2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odofuse import se2
from odofuse.declarations import MotionOptions
from odofuse.options import coerce


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
