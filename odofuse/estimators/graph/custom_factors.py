"""Factors GTSAM has no built-in factor for (``gtsam.CustomFactor``, analytic Jacobians).

The measurement models of :mod:`odofuse.measurements` give the factors of known landmarks;
this module adds

* :func:`range_landmark_factor`: range ``z = s * ||p - l|| + o`` to a landmark *variable*
  ``l`` with range scale ``s`` and offset ``o`` variables (SLAM with range calibration;
  GTSAM's ``RangeFactor2D`` has no scale and ``RangeFactorWithTransformBias2D`` no scale);
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


def range_landmark_factor(pose_key, landmark_key, z, noise, scale_key=None, offset_key=None):
    """Range from a pose to a landmark variable with optional scale/offset variables.

    ``h = s ||p - l|| + o`` (m) with ``p`` the pose position and ``l`` the landmark
    (``Point2``), ``s`` and ``o`` 1-vectors (nominal 1 and 0 when their key is ``None``).
    The error is ``h - z`` (GTSAM's sign); Jacobians are analytic, w.r.t. the Pose2 body
    tangent ``[v_x, v_y, omega]`` (``d p = R(theta) d v``), the landmark and ``s``, ``o``.

    Returns
    -------
    gtsam.CustomFactor
    """
    import gtsam

    keys = [pose_key, landmark_key]
    if scale_key is not None:
        keys.append(scale_key)
    if offset_key is not None:
        keys.append(offset_key)
    z = float(z)

    def error(this, values, H):
        p = values.atPose2(pose_key)
        lm = values.atPoint2(landmark_key)
        s = float(values.atVector(scale_key)[0]) if scale_key is not None else 1.0
        o = float(values.atVector(offset_key)[0]) if offset_key is not None else 0.0
        dx, dy = p.x() - lm[0], p.y() - lm[1]
        d = max(math.hypot(dx, dy), 1e-9)
        if H is not None:
            ux, uy = dx / d, dy / d
            c, sn = math.cos(p.theta()), math.sin(p.theta())
            H[0] = np.array([[s * (ux * c + uy * sn), s * (-ux * sn + uy * c), 0.0]])
            H[1] = np.array([[-s * ux, -s * uy]])
            i = 2
            if scale_key is not None:
                H[i] = np.array([[d]])
                i += 1
            if offset_key is not None:
                H[i] = np.array([[1.0]])
        return np.array([s * d + o - z])

    return gtsam.CustomFactor(noise, gtsam.KeyVector(keys), error)


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
        Analytic Jacobians from GTSAM's ``between``/``compose``/``Expmap``/``Logmap``.
    """
    import gtsam

    D = gtsam.Pose2(*np.asarray(delta0, dtype=float))
    G = np.asarray(G, dtype=float)
    p0 = np.asarray(p0, dtype=float)

    def error(this, values, H):
        xi, xj = values.atPose2(key_i), values.atPose2(key_j)
        dp = np.asarray(values.atVector(calib_key), dtype=float) - p0
        He = np.zeros((3, 3), order="F")
        E = gtsam.Pose2.Expmap(G @ dp, He)
        Hc1, Hc2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        m = D.compose(E, Hc1, Hc2)
        H1, H2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        h = xi.between(xj, H1, H2)
        Hm, Hh = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        r = m.between(h, Hm, Hh)
        Hl = np.zeros((3, 3), order="F")
        e = np.asarray(gtsam.Pose2.Logmap(r, Hl)).reshape(3)
        if H is not None:
            H[0] = Hl @ Hh @ H1
            H[1] = Hl @ Hh @ H2
            H[2] = Hl @ Hm @ Hc2 @ He @ G
        return e

    return gtsam.CustomFactor(noise, gtsam.KeyVector([key_i, key_j, calib_key]), error)


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
