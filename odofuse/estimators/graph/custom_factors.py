"""Factors GTSAM has no built-in factor for (``gtsam.CustomFactor``, analytic Jacobians).

The measurement models of :mod:`odofuse.measurements` give the sensors' factors (the range
to a beacon or a landmark variable with scale and offset variables:
:func:`odofuse.measurements.landmarks.range_factor`); this module adds

* :func:`frozen_calibration_factor`: a unary sensor factor whose calibration states are
  constants (iSAM2's ``calibration_freeze``: once converged, new factors stop touching the
  global calibration variables);
* :func:`calibrated_between_factor`: odometry between factor corrected to first order in
  odometry calibration parameters (wheel radius ratio, track scale, ds/dtheta scale, bias);
* :func:`gyro_increment_factor`: a pre-integrated gyro heading increment with a bias
  variable under a robust loss (without a robust loss the graph uses an exact built-in
  ``LinearContainerFactor``, :meth:`odofuse.estimators.graph.factors.Factors.gyro`).

They are placed in the graph by :class:`odofuse.estimators.graph.factors.Factors`; a graph
holding any of them is solved by :func:`odofuse.estimators.graph.solvers.levenberg_marquardt`.
"""

from __future__ import annotations

import math

import numpy as np


def calibrated_between_factor(key_i, key_j, calib_key, delta0, G, p0, noise):
    """Odometry between factor whose measurement depends on odometry calibration parameters.

    The pre-integrated relative pose is corrected to first order in the parameters ``p``
    (as the bias correction of IMU pre-integration, Forster et al. 2017)::

        m(p) = delta0 * Exp(G (p - p0))
        e    = Log(m(p)^-1 * (x_i^-1 * x_j))          (GTSAM's BetweenFactor error)

    Parameters
    ----------
    key_i, key_j : int
        Pose2 keys of the interval's start and end keyframes.
    calib_key : int
        Key of the parameter vector ``p`` (m,).
    delta0 : ndarray (3,)
        Pre-integrated relative pose at the nominal parameters ``p0``.
    G : ndarray (3, m)
        ``d xi / d p``: tangent (body frame at the interval end) change of the relative pose
        per unit parameter change, from the pre-integration.
    p0 : ndarray (m,)
    noise : gtsam.noiseModel.Base
        The pre-integrated covariance (and optional robust loss).

    Returns
    -------
    gtsam.CustomFactor
        The SE(2) algebra in closed form on Python floats (:func:`_jr_inverse`,
        :func:`_se2_log`); equal to GTSAM's ``Expmap``/``compose``/``between``/``Logmap``
        chain to 1e-11 and its Jacobians to 1e-9 where GTSAM's formulas keep their digits
        (below about 1e-3 rad they lose them to cancellation; these switch to series:
        ``tests/test_graph.py``). Plaza1's smoother
        evaluates 5,460 of these factors 12 times, and GTSAM's per-call chain (eight
        Jacobian buffers, five bound calls) cost most of its time (docs/speed.md).
    """
    import gtsam

    dx, dy, dth = (float(a) for a in np.asarray(delta0, dtype=float))
    cd, sd = math.cos(dth), math.sin(dth)
    G = np.asarray(G, dtype=float)
    g = G.tolist()
    p0 = np.asarray(p0, dtype=float)

    def error(this, values, H):
        pi, pj = values.atPose2(key_i), values.atPose2(key_j)
        vx, vy, w = (G @ (values.atVector(calib_key) - p0)).tolist()
        # m = delta0 * Exp(v)
        a, b = _sinc(w), _cosc(w)
        ex, ey = a * vx - b * vy, b * vx + a * vy
        mx, my, mth = dx + cd * ex - sd * ey, dy + sd * ex + cd * ey, dth + w
        # h = x_i^-1 x_j
        ti = pi.theta()
        ci, si = math.cos(ti), math.sin(ti)
        tx, ty = pj.x() - pi.x(), pj.y() - pi.y()
        hx, hy, hth = ci * tx + si * ty, -si * tx + ci * ty, pj.theta() - ti
        # r = m^-1 h, e = Log(r)
        cm, sm = math.cos(mth), math.sin(mth)
        ux, uy = hx - mx, hy - my
        rx, ry = cm * ux + sm * uy, -sm * ux + cm * uy
        rth = math.remainder(hth - mth, 2.0 * math.pi)
        e = _se2_log(rx, ry, rth)
        if H is not None:
            # Each 3 x 3 factor is [[A, t], [0, 1]] with A = [[p, -q], [q, p]] (a rotation
            # times a scale): products on the four numbers (p, q, t1, t2), then G's columns.
            J = _jr_inverse(*e)
            Hh = _compose(J, _adjoint_of_inverse(hx, hy, hth))
            jv = (a, -b, *_se2_third_column(vx, vy, w))  # ExpmapDerivative at v (a, b above)
            Hm = _compose(_compose(J, _adjoint_of_inverse(rx, ry, rth)), jv)
            p, q, t1, t2 = Hh
            H[0] = np.array([[-p, q, -t1], [-q, -p, -t2], [0.0, 0.0, -1.0]])
            p, q, t1, t2 = J
            H[1] = np.array([[p, -q, t1], [q, p, t2], [0.0, 0.0, 1.0]])
            p, q, t1, t2 = Hm
            H[2] = np.array(
                [
                    [q * g1 - p * g0 - t1 * g2 for g0, g1, g2 in zip(*g, strict=True)],
                    [-q * g0 - p * g1 - t2 * g2 for g0, g1, g2 in zip(*g, strict=True)],
                    [-g2 for g2 in g[2]],
                ]
            )
        return np.array(e)

    return gtsam.CustomFactor(noise, gtsam.KeyVector([key_i, key_j, calib_key]), error)


# ----------------------------------------------------------------------------- SE(2) algebra
# GTSAM's Pose2 conventions: tangent [v_x, v_y, omega], perturbations on the right
# (x * Exp(d)), AdjointMap [[c, -s, y], [s, c, -x], [0, 0, 1]]. Series below |w| < 1e-3
# (their truncation error is below 1e-18).
_SMALL = 1e-3


def _sinc(w: float) -> float:
    """``sin(w) / w``."""
    if abs(w) < _SMALL:
        w2 = w * w
        return 1.0 - w2 / 6.0 * (1.0 - w2 / 20.0)
    return math.sin(w) / w


def _cosc(w: float) -> float:
    """``(1 - cos(w)) / w``."""
    if abs(w) < _SMALL:
        w2 = w * w
        return 0.5 * w * (1.0 - w2 / 12.0 * (1.0 - w2 / 30.0))
    return (1.0 - math.cos(w)) / w


def _half_cot(w: float) -> tuple[float, float]:
    """``(w / 2, k)`` with ``k = (w / 2) cot(w / 2)``."""
    half = 0.5 * w
    if abs(w) < _SMALL:
        return half, 1.0 - w * w / 12.0 * (1.0 + w * w / 60.0)
    return half, half * math.cos(half) / math.sin(half)


def _se2_log(x: float, y: float, th: float) -> tuple[float, float, float]:
    """``Log`` of the pose ``(x, y, th)``, ``th`` in [-pi, pi]: ``V(th)^-1 t`` with
    ``V^-1 = [[k, th/2], [-th/2, k]]`` (:func:`_half_cot`)."""
    half, k = _half_cot(th)
    return k * x + half * y, -half * x + k * y, th


def _se2_third_column(vx: float, vy: float, w: float) -> tuple[float, float]:
    """The translation rows of the right Jacobian's last column at ``(vx, vy, w)``:
    ``(vx (w - sin w) - vy (1 - cos w)) / w^2`` and ``(vx (1 - cos w) + vy (w - sin w)) / w^2``."""
    if abs(w) < _SMALL:
        w2 = w * w
        p = w / 6.0 * (1.0 - w2 / 20.0)  # (w - sin w) / w^2
        q = 0.5 - w2 / 24.0 * (1.0 - w2 / 30.0)  # (1 - cos w) / w^2
    else:
        p, q = (w - math.sin(w)) / (w * w), (1.0 - math.cos(w)) / (w * w)
    return vx * p - vy * q, vx * q + vy * p


# A 3 x 3 matrix [[p, -q, t1], [q, p, t2], [0, 0, 1]] as the four numbers (p, q, t1, t2).


def _jr_inverse(vx: float, vy: float, w: float) -> tuple:
    """GTSAM's ``Pose2.LogmapDerivative`` at the pose whose ``Log`` is ``(vx, vy, w)``: the
    inverse of the right Jacobian ``[[A, c], [0, 1]]`` (``Pose2.ExpmapDerivative``, ``A =
    [[sinc w, cosc w], [-cosc w, sinc w]]``, ``c`` from :func:`_se2_third_column`):
    ``[[A^-1, -A^-1 c], [0, 1]]`` with ``A^-1 = [[k, -w/2], [w/2, k]]``, ``k = (w/2) cot(w/2)``."""
    half, k = _half_cot(w)
    c1, c2 = _se2_third_column(vx, vy, w)
    return k, half, -(k * c1 - half * c2), -(half * c1 + k * c2)


def _adjoint_of_inverse(x: float, y: float, th: float) -> tuple:
    """``AdjointMap`` of the inverse of the pose ``(x, y, th)``: the inverse is
    ``(-R^T t, -th)``, and GTSAM's Pose2 ``AdjointMap`` is ``[[c, -s, y], [s, c, -x], [0, 0,
    1]]``."""
    c, s = math.cos(th), math.sin(th)
    ix, iy = -(c * x + s * y), -(-s * x + c * y)
    return c, -s, iy, -ix


def _compose(m1: tuple, m2: tuple) -> tuple:
    """The product of two such matrices."""
    p1, q1, a1, b1 = m1
    p2, q2, a2, b2 = m2
    return p1 * p2 - q1 * q2, q1 * p2 + p1 * q2, p1 * a2 - q1 * b2 + a1, q1 * a2 + p1 * b2 + b1


def frozen_calibration_factor(model, key, row, constants, noise=None):
    """A unary sensor factor on pose ``key`` with the model's calibration states held constant.

    The same error as ``model.factor(key, row, calib_keys, noise)`` (``h(x, c) - z`` with the
    model's angle wrapping, whitened by ``noise`` or ``R(row)``), evaluated at fixed values
    ``c`` of the calibration states instead of reading them from graph variables, so the
    factor involves the pose only. Jacobian: the model's analytic ``H`` w.r.t. world
    ``[x, y, theta]`` moved to GTSAM's Pose2 body tangent, ``H @ blockdiag(R(theta), 1)``.

    Parameters
    ----------
    model : odofuse.measurements.MeasurementModel
        A unary model (``h(x, row)`` of the pose and its ``calib_states``).
    key : int
        GTSAM key of the ``Pose2`` variable.
    row : mapping
        The sensor row.
    constants : dict[str, float]
        State name -> value (units of the state, e.g. ``range_scale`` [-], ``range_offset``
        [m]); states of ``model.calib_states`` not given take their nominal values.
    noise : gtsam.noiseModel.Base, optional
        Noise model (robust wrapper included); default ``model.noise(row)``.

    Returns
    -------
    gtsam.CustomFactor
    """
    import gtsam

    names = [s for s in getattr(model, "calib_states", ()) if s in constants]
    consts = np.array([float(constants[s]) for s in names])
    bound = model.bind({s: 3 + i for i, s in enumerate(names)})
    z = model.z(row)

    def error(this, values, H):
        p = values.atPose2(key)
        x = np.concatenate([[p.x(), p.y(), p.theta()], consts])
        err = -bound.residual(z, bound.h(x, row))
        if H is not None:
            c, s = math.cos(x[2]), math.sin(x[2])
            T = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            H[0] = bound.H(x, row)[:, :3] @ T
        return err

    return gtsam.CustomFactor(model.noise(row, noise), gtsam.KeyVector([key]), error)


def gyro_increment_factor(key_i, key_j, bias_key, dtheta, T, noise):
    """Pre-integrated gyro heading increment between two poses with a bias variable.

    ``e = wrap(theta_j - theta_i + b T - dtheta)`` (rad): the measured heading change
    ``dtheta`` over ``T`` s of gyro data, corrected by the bias ``b`` (rad/s, a 1-vector).
    Jacobians w.r.t. the Pose2 body tangents ``[0, 0, -1]``, ``[0, 0, 1]`` and ``T``.

    Returns
    -------
    gtsam.CustomFactor
    """
    import gtsam

    from odofuse.se2 import wrap

    dtheta, T = float(dtheta), float(T)
    Hi, Hj, Hb = np.array([[0.0, 0.0, -1.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([[T]])

    def error(this, values, H):
        a, b = values.atPose2(key_i).theta(), values.atPose2(key_j).theta()
        bias = float(values.atVector(bias_key)[0])
        if H is not None:
            H[0], H[1], H[2] = Hi, Hj, Hb
        return np.array([float(wrap(b - a + bias * T - dtheta))])

    return gtsam.CustomFactor(noise, gtsam.KeyVector([key_i, key_j, bias_key]), error)
