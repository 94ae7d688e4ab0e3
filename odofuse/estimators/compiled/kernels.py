"""numba kernels of the compiled offline core (imported only when numba is).

Each kernel is the scalar form of a pure-Python reference, written so that it can be checked
against it to 1e-9 (``tests/test_compiled.py``):

* :func:`dr_linear` / :func:`dr_generic`: :func:`odofuse.motion.dead_reckon` (``MotionModel``
  ``predict`` step by step, Siegwart's ``F_p P F_p^T + F_u Sigma_u F_u^T``);
* :func:`ekf_offline`: the :class:`~odofuse.estimators.localizer.Localizer` event loop with
  :class:`~odofuse.estimators.ekf.EkfBackend` (odometry prediction, optionally with the
  odometry-calibration states, step splitting at measurement times, filterpy's Joseph-form
  update and the chi-square gate) for range-to-beacon, GPS, compass and gyro-rate sensors;
* :func:`filter_offline` with UKF weights: the same event loop with
  :class:`~odofuse.estimators.ukf.UkfBackend` (filterpy's Merwe sigma points and weights,
  ``ukf._psd_sqrt``, the circular mean in theta and the heading clones, the sigma points
  regenerated before each update), on the EKF's measurement functions (:func:`_measure`) and
  calibrated inputs (``tests/test_compiled_ukf.py``);
* :func:`pf_predict`, :func:`pf_moments`, :func:`pf_reweight`, :func:`pf_mean`,
  :func:`pf_gram`, :func:`pf_cov`: the
  :class:`~odofuse.estimators.particle.ParticleBackend`'s propagation, innovation moments and
  reweighting, and cloud mean and covariance, on the random numbers the backend's numpy
  generator draws (``tests/test_compiled_particle.py``).

Integrator codes: 0 ``euler``, 1 ``rk2``, 2 ``exact``, 3 ``euler_end``. Compiled with
``cache=True``: the first run on a machine compiles and stores the machine code next to this
file (``__pycache__``); later runs load it.

It is over 1,200 lines on purpose: it is the only module that imports numba, so a run
that does not compile never pays numba's import, and the kernels that call each other (the
EKF and the UKF share the event loop, the motion and the measurement functions) are compiled
together.
"""

from __future__ import annotations

import math
import os

import numpy as np
from numba import njit

TWO_PI = 2.0 * math.pi
_SERIES_BELOW = 1e-2
#: :func:`dr_linear`: half-turns ``|w / 2|`` (rad) below which a step's trigonometry is
#: polynomial (:func:`_sinc_cos`) and the heading's cosine and sine follow from the previous
#: step's by the angle-addition formulas; larger ones call ``math.cos`` / ``math.sin``.
_POLY_BELOW = 0.25
#: :func:`dr_linear`: steps between re-anchoring that recurrence on ``math.cos`` /
#: ``math.sin`` of the wrapped heading, so its rounding drift stays within a few hundred ulp.
_ANCHOR = 256

#: Stream kinds of :func:`ekf_offline`.
RANGE, GPS, COMPASS, GYRO = 0, 1, 2, 3


@njit(cache=True, inline="always")
def _wrap(a):
    return (a + math.pi) % TWO_PI - math.pi


@njit(cache=True, inline="always")
def _increment(integ, w, vx, vy, Jt):
    """Body increment ``(dx, dy, dtheta)`` of twist ``(w, vx, vy)``; fills ``Jt`` (3, 3)."""
    Jt[2, 0], Jt[2, 1], Jt[2, 2] = 1.0, 0.0, 0.0
    if integ == 2:
        half = 0.5 * w
        sh, ch = math.sin(half), math.cos(half)
        sinc_half = 1.0 if half == 0.0 else sh / half
        A, B = sinc_half * ch, sinc_half * sh
        if abs(w) < _SERIES_BELOW:
            w2 = w * w
            dA = w * (-1.0 / 3.0 + w2 * (1.0 / 30.0 + w2 * (-1.0 / 840.0 + w2 / 45360.0)))
            dB = 0.5 + w2 * (-1.0 / 8.0 + w2 * (1.0 / 144.0 + w2 * (-1.0 / 5760.0 + w2 / 403200.0)))
        else:
            s2, omc = 2.0 * sh * ch, 2.0 * sh * sh
            dA = (w * (1.0 - omc) - s2) / (w * w)
            dB = (w * s2 - omc) / (w * w)
        Jt[0, 0], Jt[0, 1], Jt[0, 2] = dA * vx - dB * vy, A, -B
        Jt[1, 0], Jt[1, 1], Jt[1, 2] = dB * vx + dA * vy, B, A
        return A * vx - B * vy, B * vx + A * vy, w
    if integ == 0:
        Jt[0, 0], Jt[0, 1], Jt[0, 2] = 0.0, 1.0, 0.0
        Jt[1, 0], Jt[1, 1], Jt[1, 2] = 0.0, 0.0, 1.0
        return vx, vy, w
    f = 0.5 if integ == 1 else 1.0
    c, s = math.cos(f * w), math.sin(f * w)
    Jt[0, 0], Jt[0, 1], Jt[0, 2] = f * (-s * vx - c * vy), c, -s
    Jt[1, 0], Jt[1, 1], Jt[1, 2] = f * (c * vx - s * vy), s, c
    return c * vx - s * vy, s * vx + c * vy, w


@njit(cache=True)
def _pose_step(pose, d0, d1, d2, P, Fu, var, with_cov):
    """``pose <- pose (+) d`` and ``P <- F_p P F_p^T + F_u diag(var) F_u^T`` (body ``F_u``).

    ``Fu`` (3, n) holds ``J_delta_u`` on entry (body frame) and is rotated in place.
    """
    th = pose[2]
    c, s = math.cos(th), math.sin(th)
    dxw = c * d0 - s * d1
    dyw = s * d0 + c * d1
    pose[0] += dxw
    pose[1] += dyw
    pose[2] = _wrap(th + d2)
    if not with_cov:
        return
    n = Fu.shape[1]
    for j in range(n):
        a, b = Fu[0, j], Fu[1, j]
        Fu[0, j] = c * a - s * b
        Fu[1, j] = s * a + c * b
    # F_p = I + e c^T with e = (-dyw, dxw, 0) on the theta column.
    e0, e1 = -dyw, dxw
    p02, p12, p22 = P[0, 2], P[1, 2], P[2, 2]
    n00 = P[0, 0] + 2.0 * e0 * p02 + e0 * e0 * p22
    n01 = P[0, 1] + e0 * p12 + e1 * p02 + e0 * e1 * p22
    n11 = P[1, 1] + 2.0 * e1 * p12 + e1 * e1 * p22
    n02 = p02 + e0 * p22
    n12 = p12 + e1 * p22
    q00 = q01 = q02 = q11 = q12 = q22 = 0.0
    for j in range(n):
        v = var[j]
        f0, f1, f2 = Fu[0, j], Fu[1, j], Fu[2, j]
        q00 += f0 * v * f0
        q01 += f0 * v * f1
        q02 += f0 * v * f2
        q11 += f1 * v * f1
        q12 += f1 * v * f2
        q22 += f2 * v * f2
    P[0, 0], P[1, 1], P[2, 2] = n00 + q00, n11 + q11, p22 + q22
    P[0, 1] = P[1, 0] = n01 + q01
    P[0, 2] = P[2, 0] = n02 + q02
    P[1, 2] = P[2, 1] = n12 + q12


@njit(cache=True, inline="always")
def _dsinc_half(h, sh, ch):
    """d/dw of sinc(w/2) (``motion._dsinc_half``) at ``h = w/2``, given ``sin h`` and
    ``cos h``."""
    if abs(h) < 0.05:
        h2 = h * h
        return 0.5 * (h * (-1.0 / 3.0 + h2 * (1.0 / 30.0 + h2 * (-1.0 / 840.0 + h2 / 45360.0))))
    return 0.5 * (h * ch - sh) / (h * h)


@njit(cache=True, inline="always")
def _sinc_cos(h):
    """``sin(h) / h`` and ``cos(h)`` by their Taylor polynomials, for ``|h| <``
    :data:`_POLY_BELOW` (to the ``h^10`` and ``h^12`` terms: the first omitted term is below
    1e-18 of the value there, under half an ulp)."""
    h2 = h * h
    sinc = 1.0 + h2 * (
        -1.0 / 6.0
        + h2 * (1.0 / 120.0 + h2 * (-1.0 / 5040.0 + h2 * (1.0 / 362880.0 - h2 / 39916800.0)))
    )
    cos_h = 1.0 + h2 * (
        -0.5
        + h2
        * (
            1.0 / 24.0
            + h2
            * (-1.0 / 720.0 + h2 * (1.0 / 40320.0 + h2 * (-1.0 / 3628800.0 + h2 / 479001600.0)))
        )
    )
    return sinc, cos_h


@njit(cache=True)
def dr_linear(pose0, P0, U, M, K, floor, integ, with_cov, poses, covs):
    """Dead reckoning of a drive with ``twist = M u`` and ``var = K |u| + floor``.

    The chord form of ``motion.dead_reckon`` (``z = g (v_x + i v_y) e^{i phi}``) with its
    Jacobian rows for ``F_u``; the pose and the six covariance entries live in scalars (no
    per-step arrays). No transcendental call on an ordinary step: ``sin``/``cos`` of the half
    turn come from Taylor polynomials (:func:`_sinc_cos`, below :data:`_POLY_BELOW`) and
    ``e^{i phi}`` and the next ``e^{i theta}`` from the current ``e^{i theta}`` by rotation
    (angle addition); every :data:`_ANCHOR` steps, and on any larger turn, the step takes
    ``math.cos``/``math.sin`` of the wrapped heading as the reference does and re-anchors the
    rotation there. Three libm calls per step were the kernel's cost (issue 17); the
    difference to the reference stays at rounding level (``tests/test_compiled.py``).

    Parameters
    ----------
    pose0 : (3,), P0 : (3, 3)
    U : (N, n) drive inputs; M : (3, n); K : (n, n); floor : (n,)
    integ : int
        Integrator code.
    with_cov : bool
    poses : (N+1, 3) out; covs : (N+1, 3, 3) out (untouched unless ``with_cov``)
    """
    n = U.shape[1]
    x, y, th = pose0[0], pose0[1], pose0[2]
    ct = st = 0.0
    left = 0  # the first step anchors
    p00, p11, p22 = P0[0, 0], P0[1, 1], P0[2, 2]
    p01 = 0.5 * (P0[0, 1] + P0[1, 0])
    p02 = 0.5 * (P0[0, 2] + P0[2, 0])
    p12 = 0.5 * (P0[1, 2] + P0[2, 1])
    poses[0, 0], poses[0, 1], poses[0, 2] = x, y, th
    if with_cov:
        covs[0, 0, 0], covs[0, 0, 1], covs[0, 0, 2] = p00, p01, p02
        covs[0, 1, 0], covs[0, 1, 1], covs[0, 1, 2] = p01, p11, p12
        covs[0, 2, 0], covs[0, 2, 1], covs[0, 2, 2] = p02, p12, p22
    for k in range(U.shape[0]):
        w = vx = vy = 0.0
        for j in range(n):
            u = U[k, j]
            w += M[0, j] * u
            vx += M[1, j] * u
            vy += M[2, j] * u
        half = 0.5 * w
        if left > 0 and abs(half) < _POLY_BELOW:
            left -= 1
            sinc, ch = _sinc_cos(half)
            sh = half * sinc
            if integ == 0:  # phi = theta, then turn by w = 2 half
                c, s = ct, st
                c2, s2 = ch * ch - sh * sh, 2.0 * sh * ch
                ct, st = c * c2 - s * s2, s * c2 + c * s2
            elif integ == 3:  # phi = theta + w, the next heading
                c2, s2 = ch * ch - sh * sh, 2.0 * sh * ch
                ct, st = ct * c2 - st * s2, st * c2 + ct * s2
                c, s = ct, st
            else:  # phi = theta + half, then the other half
                c, s = ct * ch - st * sh, st * ch + ct * sh
                ct, st = c * ch - s * sh, s * ch + c * sh
            th += w
            if not (-math.pi <= th < math.pi):
                th = _wrap(th)
        else:
            left = _ANCHOR
            if integ == 0:
                phi = th
            elif integ == 3:
                phi = th + w
            else:
                phi = th + half
            c, s = math.cos(phi), math.sin(phi)
            sh, ch = math.sin(half), math.cos(half)
            sinc = 1.0 if half == 0.0 else sh / half
            th = _wrap(th + w)
            ct, st = math.cos(th), math.sin(th)
        g = sinc if integ == 2 else 1.0
        zr, zi = c * vx - s * vy, s * vx + c * vy
        dxw, dyw = g * zr, g * zi
        if with_cov:
            if integ == 2:
                a, b = _dsinc_half(half, sh, ch), 0.5 * g
                jw0, jw1 = zr * a - zi * b, zr * b + zi * a
            elif integ == 1:
                jw0, jw1 = -0.5 * zi, 0.5 * zr
            elif integ == 3:
                jw0, jw1 = -zi, zr
            else:
                jw0 = jw1 = 0.0
            gc, gs = g * c, g * s
            q00 = q01 = q02 = q11 = q12 = q22 = 0.0
            for j in range(n):
                v = floor[j]
                for i in range(n):
                    v += K[j, i] * abs(U[k, i])
                m0, m1, m2 = M[0, j], M[1, j], M[2, j]
                f0 = jw0 * m0 + gc * m1 - gs * m2
                f1 = jw1 * m0 + gs * m1 + gc * m2
                f0v, f1v = f0 * v, f1 * v
                q00 += f0v * f0
                q01 += f0v * f1
                q02 += f0v * m0
                q11 += f1v * f1
                q12 += f1v * m0
                q22 += m0 * v * m0
            e0, e1 = -dyw, dxw
            n00 = p00 + 2.0 * e0 * p02 + e0 * e0 * p22
            n01 = p01 + e0 * p12 + e1 * p02 + e0 * e1 * p22
            n11 = p11 + 2.0 * e1 * p12 + e1 * e1 * p22
            n02 = p02 + e0 * p22
            n12 = p12 + e1 * p22
            p00, p01, p11 = n00 + q00, n01 + q01, n11 + q11
            p02, p12, p22 = n02 + q02, n12 + q12, p22 + q22
            covs[k + 1, 0, 0], covs[k + 1, 0, 1], covs[k + 1, 0, 2] = p00, p01, p02
            covs[k + 1, 1, 0], covs[k + 1, 1, 1], covs[k + 1, 1, 2] = p01, p11, p12
            covs[k + 1, 2, 0], covs[k + 1, 2, 1], covs[k + 1, 2, 2] = p02, p12, p22
        x += dxw
        y += dyw
        poses[k + 1, 0], poses[k + 1, 1], poses[k + 1, 2] = x, y, th


@njit(cache=True)
def dr_generic(pose, P, twist, J_tu, var, integ, with_cov, poses, covs):
    """Dead reckoning of one block from precomputed twists ``(B, 3)``, ``J_twist_u``
    ``(B, 3, n)`` and input variances ``(B, n)`` (any drive, any error model).

    ``pose`` (3,) and ``P`` (3, 3) are advanced in place; ``poses`` ``(B, 3)`` and ``covs``
    ``(B, 3, 3)`` receive the pose after each step.
    """
    n = J_tu.shape[2]
    Jt = np.empty((3, 3))
    Fu = np.empty((3, n))
    for k in range(twist.shape[0]):
        d0, d1, d2 = _increment(integ, twist[k, 0], twist[k, 1], twist[k, 2], Jt)
        if with_cov:
            for j in range(n):
                for r in range(3):
                    Fu[r, j] = (
                        Jt[r, 0] * J_tu[k, 0, j]
                        + Jt[r, 1] * J_tu[k, 1, j]
                        + Jt[r, 2] * J_tu[k, 2, j]
                    )
        _pose_step(pose, d0, d1, d2, P, Fu, var[k if with_cov else 0], with_cov)
        poses[k] = pose
        if with_cov:
            covs[k] = P


# ----------------------------------------------------------------------------- EKF
@njit(cache=True)
def _work(n, m):
    """Scratch buffers of the EKF kernels (allocated once per run, not per step)."""
    return (
        np.empty((3, 3)),  # 0 Jt
        np.empty((3, m)),  # 1 Fu
        np.empty(m),  # 2 var
        np.empty(m),  # 3 uc (calibrated input) / u part
        np.empty(n),  # 4 v
        np.empty((n, n)),  # 5 F
        np.empty((n, n)),  # 6 FP / A
        np.empty((2, n)),  # 7 H
        np.empty((n, 2)),  # 8 PHT
        np.empty((n, 2)),  # 9 K
        np.empty((2, n)),  # 10 HP
        np.empty((n, 2)),  # 11 AH
        np.empty((m, 3)),  # 12 Jc (du'/dp)
        np.empty(m),  # 13 the step's input part
        np.empty(5),  # 14 the last update's innovation and its covariance
    )


@njit(cache=True)
def _calibrated_input(x, up, dt, cal, cidx, uc):
    """``uc`` (m,): the input ``up`` through the odometry calibration of state ``x``
    (``OdometryCalibration.apply``; ``cal`` 0 none, 1 increments, 2 two symmetric wheels)."""
    for j in range(up.shape[0]):
        uc[j] = up[j]
    if cal == 1:
        uc[0] = x[cidx[0]] * up[0]
        uc[1] = x[cidx[1]] * up[1] + x[cidx[2]] * dt
    elif cal == 2:
        E, Eb = x[cidx[0]], x[cidx[1]]
        R = up[1] * 2.0 * E / (1.0 + E)
        L = up[0] * 2.0 / (1.0 + E)
        mm, hh = 0.5 * (R + L), 0.5 * (R - L) / Eb
        uc[0], uc[1] = mm - hh, mm + hh
        if cidx.shape[0] > 2:  # wheel_radius_scale E_s: every angle times E_s
            uc[0], uc[1] = x[cidx[2]] * uc[0], x[cidx[2]] * uc[1]


@njit(cache=True)
def _twist(M, uc):
    """``(w, vx, vy) = M uc``."""
    w = vx = vy = 0.0
    for j in range(uc.shape[0]):
        w += M[0, j] * uc[j]
        vx += M[1, j] * uc[j]
        vy += M[2, j] * uc[j]
    return w, vx, vy


@njit(cache=True)
def _input_noise(integ, M, K, floor, rate, uc, dt, th, Jt, Fu, var):
    """Body increment ``(d0, d1, d2)`` of input ``uc`` over ``dt`` s; fills ``var`` (m,) with
    the input variances (``K |uc| + floor + rate dt``) and ``Fu`` (3, m) with the world-frame
    ``J_b(th) J_delta_u``, so that ``F_u diag(var) F_u^T`` is the step's process noise."""
    m = uc.shape[0]
    w, vx, vy = _twist(M, uc)
    d0, d1, d2 = _increment(integ, w, vx, vy, Jt)
    for j in range(m):
        acc = floor[j] + rate[j] * dt
        for i in range(m):
            acc += K[j, i] * abs(uc[i])
        var[j] = acc
        for r in range(3):
            Fu[r, j] = Jt[r, 0] * M[0, j] + Jt[r, 1] * M[1, j] + Jt[r, 2] * M[2, j]
    c, s = math.cos(th), math.sin(th)
    for j in range(m):
        a, b = Fu[0, j], Fu[1, j]
        Fu[0, j] = c * a - s * b
        Fu[1, j] = s * a + c * b
    return d0, d1, d2


@njit(cache=True)
def _ekf_predict(x, P, u, part, dt, integ, M, K, floor, rate, cal, cidx, walk, work, scale):
    """``EkfBackend.predict`` (``cal == 0``) or ``_predict_calibrated`` (1: increments,
    2: differential / skid-steer) of the fraction ``part`` of a step (input ``u * part``),
    its input variances times ``scale`` (``noise_scale``: robust odometry, :func:`step_slip`)."""
    Jt, Fu, var, uc, v, F, FP = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    Jc = work[12]
    n = x.shape[0]
    m = u.shape[0]
    up = work[13]  # the step's input part, u * part (as the Localizer passes it)
    for j in range(m):
        up[j] = u[j] * part
    _calibrated_input(x, up, dt, cal, cidx, uc)
    th = x[2]
    d0, d1, d2 = _input_noise(integ, M, K, floor, rate, uc, dt, th, Jt, Fu, var)
    if scale != 1.0:
        for j in range(m):
            var[j] *= scale
    c, s = math.cos(th), math.sin(th)
    dxw = c * d0 - s * d1
    dyw = s * d0 + c * d1
    if cal == 0:
        # F_p P F_p^T = P + B + B^T, B = e v^T, v = P[2] + P22 e / 2 (as EkfBackend.predict)
        e0, e1 = -dyw, dxw
        h = 0.5 * P[2, 2]
        for i in range(n):
            v[i] = P[2, i]
        v[0] += h * e0
        v[1] += h * e1
        for i in range(n):
            P[0, i] += e0 * v[i]
            P[1, i] += e1 * v[i]
        for i in range(n):
            P[i, 0] += e0 * v[i]
            P[i, 1] += e1 * v[i]
    else:
        # F = I + the theta column + the calibration columns F_u du'/dp
        nc = cidx.shape[0]
        if cal == 1:
            Jc[0, 0], Jc[0, 1], Jc[0, 2] = up[0], 0.0, 0.0
            Jc[1, 0], Jc[1, 1], Jc[1, 2] = 0.0, up[1], dt
        else:
            E, Eb = x[cidx[0]], x[cidx[1]]
            g = 2.0 / (1.0 + E) ** 2
            dR, dL = up[1] * g, -up[0] * g
            R = up[1] * 2.0 * E / (1.0 + E)
            L = up[0] * 2.0 / (1.0 + E)
            dm, dh = 0.5 * (dR + dL), 0.5 * (dR - dL) / Eb
            dh_b = -0.5 * (R - L) / Eb**2
            Jc[0, 0], Jc[0, 1] = dm - dh, -dh_b
            Jc[1, 0], Jc[1, 1] = dm + dh, dh_b
            if nc > 2:  # u' = E_s f: the E_d, E_b columns times E_s, the E_s column f
                Es = x[cidx[2]]
                mm, hh = 0.5 * (R + L), 0.5 * (R - L) / Eb
                for j in range(2):
                    Jc[j, 0], Jc[j, 1] = Es * Jc[j, 0], Es * Jc[j, 1]
                Jc[0, 2], Jc[1, 2] = mm - hh, mm + hh
        for i in range(n):
            for j in range(n):
                F[i, j] = 1.0 if i == j else 0.0
        F[0, 2], F[1, 2] = -dyw, dxw
        for r in range(3):
            for q in range(nc):
                acc = 0.0
                for j in range(m):
                    acc += Fu[r, j] * Jc[j, q]
                F[r, cidx[q]] = acc
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for k in range(n):
                    acc += F[i, k] * P[k, j]
                FP[i, j] = acc
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for k in range(n):
                    acc += FP[i, k] * F[j, k]
                P[i, j] = acc
    _add_process_noise(P, Fu, var, m, walk, dt)
    if cal != 0:
        _symmetrise(P)
    x[0] += dxw
    x[1] += dyw
    x[2] = _wrap(th + d2)


@njit(cache=True)
def _measure(x, kind, aux, idx, dt, H, jac):
    """``h(x)`` ``(h0, h1)`` of a stream kind (``h1`` only for GPS), and with ``jac`` its
    Jacobian in ``H`` (2, n): ``BeaconRange`` (beacon ``aux``, scale/offset columns ``idx``),
    ``GpsPosition`` (lever arm ``aux``), ``CompassHeading`` (offset column ``idx[0]``),
    ``GyroYawRate`` (clone and bias columns ``idx``, ``dt`` since the clone)."""
    n = x.shape[0]
    d = 2 if kind == GPS else 1
    if jac:
        for r in range(d):
            for i in range(n):
                H[r, i] = 0.0
    h0 = h1 = 0.0
    if kind == RANGE:
        dx, dy = x[0] - aux[0], x[1] - aux[1]
        dist = math.hypot(dx, dy)
        scale = x[idx[0]] if idx[0] >= 0 else 1.0
        offset = x[idx[1]] if idx[1] >= 0 else 0.0
        h0 = scale * dist + offset
        if jac:
            dd = max(dist, 1e-9)
            H[0, 0], H[0, 1] = scale * dx / dd, scale * dy / dd
            if idx[0] >= 0:
                H[0, idx[0]] = dist
            if idx[1] >= 0:
                H[0, idx[1]] = 1.0
    elif kind == GPS:
        lx, ly = aux[0], aux[1]
        c, s = math.cos(x[2]), math.sin(x[2])
        h0 = x[0] + c * lx - s * ly
        h1 = x[1] + s * lx + c * ly
        if jac:
            H[0, 0] = H[1, 1] = 1.0
            H[0, 2] = -s * lx - c * ly
            H[1, 2] = c * lx - s * ly
    elif kind == COMPASS:
        off = x[idx[0]] if idx[0] >= 0 else 0.0
        h0 = _wrap(x[2] + off)
        if jac:
            H[0, 2] = 1.0
            if idx[0] >= 0:
                H[0, idx[0]] = 1.0
    else:  # GYRO
        ref = x[idx[0]] if idx[0] >= 0 else x[2]
        bias = x[idx[1]] if idx[1] >= 0 else 0.0
        h0 = _wrap(x[2] - ref) / dt + bias
        if jac:
            H[0, 2] = 1.0 / dt
            if idx[0] >= 0:
                H[0, idx[0]] = -1.0 / dt
            if idx[1] >= 0:
                H[0, idx[1]] = 1.0
    return h0, h1


@njit(cache=True)
def _ekf_update(x, P, kind, z, aux, r00, r01, r11, idx, dt, gate, work):
    """filterpy's ``ExtendedKalmanFilter.update`` (Joseph form) with the gate; returns
    ``(nis, accepted)``. The state is left unchanged when the NIS fails ``nis <= gate``.
    ``R = [[r00, r01], [r01, r11]]`` (its first entry for scalar sensors). ``work[14]``
    receives the innovation ``y0, y1`` and ``S`` ``s00, s10, s11`` (as the UKF's ``out``)."""
    A, H, PHT, Kg, HP, AH = work[6], work[7], work[8], work[9], work[10], work[11]
    out = work[14]
    n = x.shape[0]
    d = 2 if kind == GPS else 1
    h0, h1 = _measure(x, kind, aux, idx, dt, H, True)
    y0 = z[0] - h0
    y1 = z[1] - h1 if d == 2 else 0.0
    if kind == COMPASS:
        y0 = _wrap(y0)
    for i in range(n):
        for r in range(d):
            acc = 0.0
            for j in range(n):
                acc += P[i, j] * H[r, j]
            PHT[i, r] = acc
    if d == 1:
        s00 = r00
        for i in range(n):
            s00 += H[0, i] * PHT[i, 0]
        out[0], out[1], out[2], out[3], out[4] = y0, 0.0, s00, 0.0, 0.0
        i00 = 1.0 / s00
        nis = y0 * i00 * y0
        if not nis <= gate:
            return nis, False
        for i in range(n):
            Kg[i, 0] = PHT[i, 0] * i00
    else:
        s00, s01, s10, s11 = r00, r01, r01, r11
        for i in range(n):
            s00 += H[0, i] * PHT[i, 0]
            s01 += H[0, i] * PHT[i, 1]
            s10 += H[1, i] * PHT[i, 0]
            s11 += H[1, i] * PHT[i, 1]
        out[0], out[1], out[2], out[3], out[4] = y0, y1, s00, s10, s11
        det = s00 * s11 - s01 * s10
        i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
        nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i10 * y0 + i11 * y1)
        if not nis <= gate:
            return nis, False
        for i in range(n):
            Kg[i, 0] = PHT[i, 0] * i00 + PHT[i, 1] * i10
            Kg[i, 1] = PHT[i, 0] * i01 + PHT[i, 1] * i11
    for i in range(n):
        x[i] += Kg[i, 0] * y0 + (Kg[i, 1] * y1 if d == 2 else 0.0)
    # (I - KH) P (I - KH)^T + K R K^T with A = (I - KH) P:  A - (A H^T) K^T + K R K^T
    for r in range(d):
        for j in range(n):
            acc = 0.0
            for i in range(n):
                acc += H[r, i] * P[i, j]
            HP[r, j] = acc
    for i in range(n):
        for j in range(n):
            acc = P[i, j]
            for r in range(d):
                acc -= Kg[i, r] * HP[r, j]
            A[i, j] = acc
    for i in range(n):
        for r in range(d):
            acc = 0.0
            for j in range(n):
                acc += A[i, j] * H[r, j]
            AH[i, r] = acc
    for i in range(n):
        for j in range(n):
            if d == 1:
                P[i, j] = A[i, j] - AH[i, 0] * Kg[j, 0] + Kg[i, 0] * r00 * Kg[j, 0]
            else:
                k0 = Kg[i, 0] * r00 + Kg[i, 1] * r01
                k1 = Kg[i, 0] * r01 + Kg[i, 1] * r11
                P[i, j] = (
                    A[i, j]
                    - AH[i, 0] * Kg[j, 0]
                    - AH[i, 1] * Kg[j, 1]
                    + k0 * Kg[j, 0]
                    + k1 * Kg[j, 1]
                )
    x[2] = _wrap(x[2])
    return nis, True


# ----------------------------------------------------------------------------- UKF
@njit(cache=True)
def ukf_work(n, m):
    """Scratch buffers of the UKF kernels: sigma points (2n+1, n) and their images, the
    square root, the predicted measurements, the cross covariance."""
    N = 2 * n + 1
    return (
        np.empty((N, n)),  # 0 sigma points
        np.empty((N, n)),  # 1 their images under the motion
        np.empty((n, n)),  # 2 (lambda + n) P
        np.empty((n, n)),  # 3 its square root U (U^T U = A)
        np.empty((N, 2)),  # 4 h of each sigma point
        np.empty((n, 2)),  # 5 Pxz / K
        np.empty(n),  # 6 a state residual
        np.empty(m),  # 7 a sigma point's calibrated input
        np.empty(5),  # 8 the last update's innovation and its covariance
    )


@njit(cache=True)
def _psd_sqrt(A, U, tol):
    """``ukf._psd_sqrt``: ``U`` (n, n) with ``U^T U = A``, upper Cholesky, or when a pivot is
    at or below ``tol`` of its diagonal entry (a singular direction) the symmetric square
    root of the eigen-decomposition with negative eigenvalues clipped to zero."""
    n = A.shape[0]
    ok = True
    for j in range(n):
        acc = A[j, j]
        for k in range(j):
            acc -= U[k, j] * U[k, j]
        if not acc > tol * A[j, j]:
            ok = False
            break
        piv = math.sqrt(acc)
        U[j, j] = piv
        for i in range(j + 1, n):
            acc = A[j, i]
            for k in range(j):
                acc -= U[k, j] * U[k, i]
            U[j, i] = acc / piv
        for i in range(j):
            U[j, i] = 0.0
    if ok:
        return
    B = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            B[i, j] = 0.5 * (A[i, j] + A[j, i])
    vals, vecs = np.linalg.eigh(B)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                if vals[k] > 0.0:
                    acc += vecs[i, k] * math.sqrt(vals[k]) * vecs[j, k]
            U[i, j] = acc


@njit(cache=True)
def _sigma_points(x, P, c, angles, tol, uw):
    """filterpy's ``MerweScaledSigmaPoints.sigma_points`` with ``UkfBackend``'s subtract
    (angles wrapped) and square root: ``x``, ``x + U_k``, ``x - U_k`` into ``uw[0]``; ``c``
    is ``lambda + n``."""
    S, A, U = uw[0], uw[2], uw[3]
    n = x.shape[0]
    for i in range(n):
        for j in range(n):
            A[i, j] = c * P[i, j]
    _psd_sqrt(A, U, tol)
    for i in range(n):
        S[0, i] = x[i]
    for k in range(n):
        for i in range(n):
            S[k + 1, i] = x[i] + U[k, i]
            S[n + k + 1, i] = x[i] - U[k, i]
        for a in angles:
            S[k + 1, a] = _wrap(S[k + 1, a])
            S[n + k + 1, a] = _wrap(S[n + k + 1, a])


@njit(cache=True)
def _add_process_noise(P, Fu, var, m, walk, dt):
    """The filters' process noise on ``P``: ``F_u Sigma_u F_u^T`` (``Sigma_u = diag(var[:m])``,
    ``m`` inputs) on the pose block, and each state's random walk over ``dt``."""
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for j in range(m):
                acc += Fu[a, j] * var[j] * Fu[b, j]
            P[a, b] += acc
    if dt > 0:
        for i in range(P.shape[0]):
            P[i, i] += walk[i] * dt


@njit(cache=True)
def _symmetrise(P):
    """``P`` <- ``(P + P^T) / 2`` in place."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            sym = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = sym
            P[j, i] = sym


@njit(cache=True)
def _ukf_predict(
    x, P, u, part, dt, integ, M, K, floor, rate, cal, cidx, walk,
    Wm, Wc, c, angles, tol, work, uw, scale,
):  # fmt: skip
    """``UkfBackend.predict`` of the fraction ``part`` of a step: the sigma points of ``x``,
    ``P`` through ``pose (+) delta(u)`` (each with its own calibrated input when ``cal``),
    their circular mean and covariance (``unscented_transform``) plus ``Q = F_u Sigma_u
    F_u^T`` at the mean's calibrated input (``Sigma_u`` times ``scale``) and the random walk;
    ``P`` symmetrised."""
    Jt, Fu, var, uc, up = work[0], work[1], work[2], work[3], work[13]
    S, X, dx, ui = uw[0], uw[1], uw[6], uw[7]
    n = x.shape[0]
    m = u.shape[0]
    N = 2 * n + 1
    for j in range(m):
        up[j] = u[j] * part
    _calibrated_input(x, up, dt, cal, cidx, uc)
    d0, d1, d2 = _input_noise(integ, M, K, floor, rate, uc, dt, x[2], Jt, Fu, var)
    if scale != 1.0:
        for j in range(m):
            var[j] *= scale
    _sigma_points(x, P, c, angles, tol, uw)
    for i in range(N):
        if cal != 0:  # UkfBackend._fx: the sigma point's own calibration
            _calibrated_input(S[i], up, dt, cal, cidx, ui)
            w, vx, vy = _twist(M, ui)
            d0, d1, d2 = _increment(integ, w, vx, vy, Jt)
        th = S[i, 2]
        co, si = math.cos(th), math.sin(th)
        for k in range(n):
            X[i, k] = S[i, k]
        X[i, 0] = S[i, 0] + co * d0 - si * d1
        X[i, 1] = S[i, 1] + si * d0 + co * d1
        X[i, 2] = _wrap(th + d2)
    _ut_state(X, Wm, Wc, angles, x, P, dx)
    _add_process_noise(P, Fu, var, m, walk, dt)
    _symmetrise(P)


@njit(cache=True)
def _ut_state(X, Wm, Wc, angles, x, P, dx):
    """``unscented_transform`` of the state sigma points ``X`` with ``UkfBackend.x_mean``
    (circular in the ``angles``) and ``residual_x``: the mean into ``x``, the covariance
    (without noise) into ``P``."""
    N, n = X.shape
    pf_mean(X, Wm, angles, x)  # the weighted mean, circular in the angles
    for a in range(n):
        for b in range(n):
            P[a, b] = 0.0
    for i in range(N):
        for k in range(n):
            dx[k] = X[i, k] - x[k]
        for a in angles:
            dx[a] = _wrap(dx[a])
        w = Wc[i]
        for a in range(n):
            for b in range(n):
                P[a, b] += w * (dx[a] * dx[b])


@njit(cache=True)
def _ukf_update(
    x, P, kind, z, aux, r00, r01, r11, idx, dt, gate, Wm, Wc, c, angles, tol, work, uw, out
):  # fmt: skip
    """filterpy's ``UnscentedKalmanFilter.update`` through ``UkfBackend.update``: the sigma
    points of ``x``, ``P`` through the kernels' ``h`` (:func:`_measure`), the mean and residual
    circular for the compass, ``P - K S K^T`` (symmetrised) and the gate; returns ``(nis,
    accepted)``, the state unchanged when the NIS fails ``nis <= gate``. ``out`` (5,)
    receives the innovation ``y0, y1`` and ``S`` ``s00, s01, s11`` (a recovery reads them)."""
    H = work[7]
    S, Z, PK, dx = uw[0], uw[4], uw[5], uw[6]
    n = x.shape[0]
    N = 2 * n + 1
    d = 2 if kind == GPS else 1
    circ = kind == COMPASS
    _sigma_points(x, P, c, angles, tol, uw)
    for i in range(N):
        Z[i, 0], Z[i, 1] = _measure(S[i], kind, aux, idx, dt, H, False)
    z0 = z1 = 0.0
    for i in range(N):
        z0 += Wm[i] * Z[i, 0]
        z1 += Wm[i] * Z[i, 1]
    if circ:
        sa = ca = 0.0
        for i in range(N):
            sa += Wm[i] * math.sin(Z[i, 0])
            ca += Wm[i] * math.cos(Z[i, 0])
        z0 = math.atan2(sa, ca)
    s00, s01, s11 = r00, r01, r11
    for a in range(n):
        PK[a, 0] = PK[a, 1] = 0.0
    v00 = v01 = v11 = 0.0
    for i in range(N):
        e0 = Z[i, 0] - z0
        if circ:
            e0 = _wrap(e0)
        e1 = Z[i, 1] - z1 if d == 2 else 0.0
        w = Wc[i]
        v00 += w * (e0 * e0)
        v01 += w * (e0 * e1)
        v11 += w * (e1 * e1)
        for k in range(n):
            dx[k] = S[i, k] - x[k]
        for a in angles:
            dx[a] = _wrap(dx[a])
        for k in range(n):
            PK[k, 0] += w * (dx[k] * e0)
            PK[k, 1] += w * (dx[k] * e1)
    y0 = z[0] - z0
    if circ:
        y0 = _wrap(y0)
    y1 = z[1] - z1 if d == 2 else 0.0
    out[0], out[1] = y0, y1
    out[2], out[3], out[4] = s00 + v00, s01 + v01, s11 + v11
    if d == 1:
        s00 += v00
        i00 = 1.0 / s00
        nis = y0 * i00 * y0
        if not nis <= gate:
            return nis, False
        for k in range(n):
            PK[k, 0] = PK[k, 0] * i00
        for k in range(n):
            x[k] += PK[k, 0] * y0
        for a in range(n):
            for b in range(n):
                P[a, b] -= PK[a, 0] * (s00 * PK[b, 0])
    else:
        s00, s01, s11 = s00 + v00, s01 + v01, s11 + v11
        det = s00 * s11 - s01 * s01
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i01 * y0 + i11 * y1)
        if not nis <= gate:
            return nis, False
        for k in range(n):
            p0, p1 = PK[k, 0], PK[k, 1]
            PK[k, 0] = p0 * i00 + p1 * i01
            PK[k, 1] = p0 * i01 + p1 * i11
        for k in range(n):
            x[k] += PK[k, 0] * y0 + PK[k, 1] * y1
        for a in range(n):
            q0 = s00 * PK[a, 0] + s01 * PK[a, 1]
            q1 = s01 * PK[a, 0] + s11 * PK[a, 1]
            for b in range(n):
                P[a, b] -= q0 * PK[b, 0] + q1 * PK[b, 1]
    for a in angles:
        x[a] = _wrap(x[a])
    _symmetrise(P)
    return nis, True


@njit(cache=True)
def _clone(x, P, dst, src):
    x[dst] = x[src]
    for i in range(x.shape[0]):
        P[dst, i] = P[src, i]
    for i in range(x.shape[0]):
        P[i, dst] = P[i, src]
    P[dst, dst] = P[src, src]


@njit(cache=True)
def _whiten(d, out, w):
    """``w[:d] = L^-1 y`` of the innovation ``y`` and its covariance ``S = L L^T`` in ``out``
    (``y0, y1, s00, s10, s11``; lower Cholesky), NaN when ``S`` is not positive definite:
    ``status.streaming.whiten``'s formula, for the innovation-mean scan."""
    w[0] = w[1] = np.nan
    if not out[2] > 0.0:
        return
    l00 = math.sqrt(out[2])
    v0 = out[0] / l00
    if d == 1:
        w[0] = v0
        return
    l10 = out[3] / l00
    r = out[4] - l10 * l10
    if r > 0.0:
        w[0], w[1] = v0, (out[1] - l10 * v0) / math.sqrt(r)


@njit(cache=True)
def _apply(
    j, x, P, mt, ms, mz, maux, mR, skind, sidx, sgate, sR, t_ref, acc, nis, wy, work, uk
):  # fmt: skip
    """Apply measurement ``j`` (the Localizer's ``_apply``): a gyro's first reading only clones
    the heading; else the gated update of the EKF (``uk`` None), or of the UKF (``uk`` its
    weights, ``(Wm, Wc, lambda + n, angles, singular pivot, ukf_work)``);
    a gyro reading then clones the heading. ``wy[j]`` receives an accepted reading's
    whitened innovation (:func:`_whiten`)."""
    s = ms[j]
    kind = skind[s]
    tm = mt[j]
    dt = 0.0
    if kind == GYRO:
        if math.isnan(t_ref[s]) or tm <= t_ref[s]:
            t_ref[s] = tm
            _clone(x, P, sidx[s, 0], 2)
            acc[j] = 2
            return
        dt = tm - t_ref[s]
    if math.isnan(mR[j]):
        r00, r01, r11 = sR[s, 0, 0], sR[s, 0, 1], sR[s, 1, 1]
    else:
        r00, r01, r11 = mR[j], 0.0, mR[j]
    if uk is None:  # pruned when compiling: an EKF run does not compile the UKF's kernels
        v, ok = _ekf_update(
            x, P, kind, mz[j], maux[j], r00, r01, r11, sidx[s], dt, sgate[s], work
        )  # fmt: skip
        out = work[14]
    else:
        Wm, Wc, c, angles, tol, uw = uk
        v, ok = _ukf_update(
            x, P, kind, mz[j], maux[j], r00, r01, r11, sidx[s], dt, sgate[s],
            Wm, Wc, c, angles, tol, work, uw, uw[8],
        )  # fmt: skip
        out = uw[8]
    nis[j] = v
    acc[j] = 1 if ok else 0
    if ok:
        _whiten(2 if kind == GPS else 1, out, wy[j])
    if kind == GYRO:
        t_ref[s] = tm
        _clone(x, P, sidx[s, 0], 2)


@njit(cache=True)
def _predict(x, P, u, part, dt, integ, M, K, floor, rate, cal, cidx, walk, work, uk, scale):
    """The EKF's prediction (``uk`` None: the UKF's kernels are pruned when compiling) or the
    UKF's (``uk`` as :func:`_apply` takes it), input variances times ``scale``."""
    if uk is None:
        _ekf_predict(x, P, u, part, dt, integ, M, K, floor, rate, cal, cidx, walk, work, scale)
    else:
        Wm, Wc, c, angles, tol, uw = uk
        _ukf_predict(
            x, P, u, part, dt, integ, M, K, floor, rate, cal, cidx, walk,
            Wm, Wc, c, angles, tol, work, uw, scale,
        )  # fmt: skip


@njit(cache=True)
def held_rate_steps(ts, ws, tt, out):
    """``history.held_rate_integral`` of every step: ``out[k]`` (N,) the integral over
    ``(tt[k], tt[k + 1]]`` of the rates ``ws`` at times ``ts`` (sorted), each held until the
    next (the first also backwards), summed as that function sums it; NaN while the first
    rate is after the step's end."""
    S = ts.shape[0]
    i = -1  # the last sample at or before the step's start
    for k in range(tt.shape[0] - 1):
        t0, t1 = tt[k], tt[k + 1]
        if S == 0 or ts[0] > t1:
            out[k] = np.nan
            continue
        while i + 1 < S and ts[i + 1] <= t0:
            i += 1
        rate = ws[i] if i >= 0 else ws[0]
        total, cursor = 0.0, t0
        q = i + 1
        while q < S and ts[q] <= t1:
            total += rate * (ts[q] - cursor)
            cursor, rate = ts[q], ws[q]
            q += 1
        out[k] = total + rate * (t1 - cursor)


@njit(cache=True)
def _slip_scale(d, var_odo, var_ref, gate, run):
    """``slip.slip_scale``: the factor widening a step's wheel input noise."""
    if not var_odo > 0.0:
        return 1.0
    d2 = d * d
    if d2 <= gate * (var_odo + var_ref):
        return 1.0
    total = run + d
    return max(d2, total * total - run * run) / var_odo


@njit(cache=True)
def step_slip(x, P, u, span, g, M, K, floor, rate, slip, bias_idx, run, learn):
    """``slip.step_slip_scale`` of one step (input ``u`` over ``span`` s, gyro heading
    change ``g``, NaN when none): ``(scale, run)``, the step's input-noise factor and the
    summed disagreement of its slip run (0 when it does not slip). ``slip`` is ``(gate,
    gyro sigma, the bias variance when the bias is not a state)``; with a bias state
    (``bias_idx`` >= 0) ``learn`` (3,) receives ``pose_checks.record_learning``'s terms of
    the step's prior ``P``. The wheels' heading change is ``w = M[0] u`` (every integrator),
    its variance ``sum_j M[0, j]^2 var_j`` with ``var = K |u| + floor + rate span``."""
    if math.isnan(g) or not span > 0.0:
        return 1.0, 0.0
    m = u.shape[0]
    w = 0.0
    var_odo = 0.0
    for j in range(m):
        w += M[0, j] * u[j]
        v = floor[j] + rate[j] * span
        for i in range(m):
            v += K[j, i] * abs(u[i])
        var_odo += M[0, j] * M[0, j] * v
    if bias_idx >= 0:
        bias, var_b = x[bias_idx], P[bias_idx, bias_idx]
        learn[0] = P[2, 2]
        learn[1] = P[2, bias_idx] ** 2 / var_b if var_b > 0.0 else 0.0
        learn[2] = var_b
    else:
        bias, var_b = 0.0, slip[2]
    var_ref = (slip[1] * slip[1] + var_b) * span * span
    d = g - bias * span - w
    scale = _slip_scale(d, var_odo, var_ref, slip[0], run)
    return scale, run + d if scale > 1.0 else 0.0


@njit(cache=True)
def ekf_offline(
    x, P, walk, tt, U, integ, M, K, floor, rate, cal, cidx,
    mt, ms, mstep, mz, maux, mR, skind, sidx, sgate, sR,
    traj_x, traj_P, odom, acc, nis, wy, snap_k, snap_x, snap_v,
    slip_g, slip, bias_idx, slip_out, learn,
):  # fmt: skip
    """The Localizer's offline event loop with the EKF backend, over a whole log
    (:func:`filter_offline`)."""
    filter_offline(
        x, P, walk, tt, U, integ, M, K, floor, rate, cal, cidx,
        mt, ms, mstep, mz, maux, mR, skind, sidx, sgate, sR,
        traj_x, traj_P, odom, acc, nis, wy, snap_k, snap_x, snap_v,
        slip_g, slip, bias_idx, slip_out, learn, None,
    )  # fmt: skip


@njit(cache=True)
def filter_offline(
    x, P, walk, tt, U, integ, M, K, floor, rate, cal, cidx,
    mt, ms, mstep, mz, maux, mR, skind, sidx, sgate, sR,
    traj_x, traj_P, odom, acc, nis, wy, snap_k, snap_x, snap_v,
    slip_g, slip, bias_idx, slip_out, learn, uk,
):  # fmt: skip
    """The Localizer's offline event loop with the EKF backend (``uk`` None), or the UKF's,
    over a whole log (:func:`ekf_offline`; ``compiled.ukf.run``).

    Parameters
    ----------
    x : (n,), P : (n, n)
        Prior state and covariance; updated in place to the final ones.
    walk : (n,) random-walk variance per second.
    tt : (N+1,) odometry times (s); U : (N, m) drive inputs.
    integ, M, K, floor, rate : the motion model (see :func:`dr_linear`; ``rate`` per second).
    cal : 0 none, 1 increments, 2 differential; cidx : calibration state indices.
    mt, ms, mstep : (J,) measurement times, stream indices and the step that applies each
        (-1: applied to the initial state), in the Localizer's order.
    mz : (J, 2) values; maux : (J, 2) beacon position or lever arm; mR : (J,) a row's own
        variance (NaN: the stream's ``sR``).
    skind, sidx (S, 2), sgate, sR (S, 2, 2) : per-stream kind, state columns, gate, R.
    traj_x : (N+1, 3), traj_P : (N+1, 3, 3), odom : (3,), acc : (J,) int8, nis : (J,) out.
        ``acc`` is 1 accepted, 0 rejected, 2 a clone-only first gyro reading.
    wy : (J, 2) out: each accepted reading's whitened innovation (:func:`_whiten`).
    snap_k : (K,) increasing steps after which the state is copied to ``snap_x`` (K, n) and
        the covariance's diagonal to ``snap_v`` (K, n) (the calibration drift check's
        snapshots, :class:`odofuse.status.drift.Drift`).
    slip_g : (N,) or None
        Robust odometry (``slip.step_slip_scale``, :func:`step_slip`): each step's gyro
        heading change (NaN: none); None when it is off (that specialisation compiles none
        of it). ``slip`` (3,), ``bias_idx``: see
        :func:`step_slip`; ``slip_out`` (N,) receives each step's noise factor, ``learn``
        (N, 3) the ``learning`` terms of the steps that have them (else NaN).
    uk : None (the EKF; its specialisation compiles none of the UKF's kernels) or
        ``(Wm, Wc, c, angles, tol, ukf_work(n, m))``: the UKF's Merwe weights (2n+1,),
        ``c = lambda + n``, its circular states (theta, heading clones), the singular pivot
        of its square root (``SINGULAR_PIVOT``) and buffers.
    """
    n = x.shape[0]
    m = U.shape[1]
    work = _work(n, m)
    Jt = work[0]
    t_ref = np.full(skind.shape[0], np.nan)
    dummy = np.empty((3, m))
    var0 = np.empty(m)
    zero_P = np.zeros((3, 3))
    for a in range(3):
        traj_x[0, a] = x[a]
        for b in range(3):
            traj_P[0, a, b] = P[a, b]
    J = mt.shape[0]
    j = 0
    si = 0
    run = 0.0  # the summed disagreement of the current slip run (robust odometry)
    while j < J and mstep[j] == -1:
        _apply(j, x, P, mt, ms, mz, maux, mR, skind, sidx, sgate, sR, t_ref, acc, nis, wy, work, uk)
        j += 1
    for k in range(U.shape[0]):
        t0, t1 = tt[k], tt[k + 1]
        u = U[k]
        span = t1 - t0
        scale = 1.0
        if slip_g is not None:  # pruned when compiling: a run without robust odometry
            scale, run = step_slip(
                x, P, u, span, slip_g[k], M, K, floor, rate, slip, bias_idx, run, learn[k]
            )  # fmt: skip
            slip_out[k] = scale
        done = 0.0
        due = False
        while j < J and mstep[j] == k:
            due = True
            tm = mt[j]
            f = 1.0 if span <= 0.0 else min(max((tm - t0) / span, done), 1.0)
            if f > done:
                part = f - done
                _predict(
                    x, P, u, part, span * part, integ, M, K, floor, rate, cal, cidx, walk,
                    work, uk, scale,
                )  # fmt: skip
                done = f
            _apply(
                j, x, P, mt, ms, mz, maux, mR, skind, sidx, sgate, sR, t_ref, acc, nis, wy,
                work, uk,
            )  # fmt: skip
            j += 1
        if done < 1.0 or not due:
            part = 1.0 - done
            _predict(
                x, P, u, part, span * part, integ, M, K, floor, rate, cal, cidx, walk,
                work, uk, scale,
            )  # fmt: skip
        for a in range(3):
            traj_x[k + 1, a] = x[a]
            for b in range(3):
                traj_P[k + 1, a, b] = P[a, b]
        if si < snap_k.shape[0] and snap_k[si] == k:
            for a in range(n):
                snap_x[si, a] = x[a]
                snap_v[si, a] = P[a, a]
            si += 1
        # The continuous odometry pose (uncalibrated increments), for map_to_odom.
        w = vx = vy = 0.0
        for i in range(m):
            w += M[0, i] * u[i]
            vx += M[1, i] * u[i]
            vy += M[2, i] * u[i]
        d0, d1, d2 = _increment(integ, w, vx, vy, Jt)
        _pose_step(odom, d0, d1, d2, zero_P, dummy, var0, False)


@njit(cache=True)
def ekf_predict_step(x, P, u, dt, integ, M, K, floor, rate, cal, cidx, walk, scale):
    """One odometry prediction of the streaming Localizer (input ``u`` (m,) over ``dt`` s,
    input variances times ``scale``), in place on ``x`` (n,) and ``P`` (n, n):
    :func:`_ekf_predict` with ``part = 1`` (the Localizer passes the step's part already
    scaled), as :func:`ekf_offline` applies it."""
    work = _work(x.shape[0], u.shape[0])
    _ekf_predict(x, P, u, 1.0, dt, integ, M, K, floor, rate, cal, cidx, walk, work, scale)


@njit(cache=True)
def _row_arrays(z0, z1, a0, a1, i0, i1):
    """A row's values ``z``, beacon / lever arm ``aux`` and state columns ``idx`` as arrays
    (the form :func:`_apply` passes from the offline arrays)."""
    z = np.empty(2)
    z[0], z[1] = z0, z1
    aux = np.empty(2)
    aux[0], aux[1] = a0, a1
    idx = np.empty(2, dtype=np.int64)
    idx[0], idx[1] = i0, i1
    return z, aux, idx


@njit(cache=True)
def ekf_update_row(x, P, kind, z0, z1, a0, a1, r00, r01, r11, i0, i1, dt, gate, out):
    """One gated update of the streaming Localizer, in place: :func:`_ekf_update` on the
    row's values ``z`` (z0, z1), beacon position / lever arm ``(a0, a1)``, ``R`` entries and
    state columns ``(i0, i1)`` (-1: none) as :func:`_apply` passes them; ``out`` (5,)
    receives the innovation and its covariance (``y0, y1, s00, s10, s11``); returns
    ``(nis, accepted)``."""
    z, aux, idx = _row_arrays(z0, z1, a0, a1, i0, i1)
    work = _work(x.shape[0], 1)
    nis, ok = _ekf_update(x, P, kind, z, aux, r00, r01, r11, idx, dt, gate, work)
    out[:] = work[14]
    return nis, ok


@njit(cache=True)
def ukf_predict_step(
    x, P, u, dt, integ, M, K, floor, rate, cal, cidx, walk, scale, Wm, Wc, c, angles, tol
):
    """One odometry prediction of the streaming UKF Localizer, in place: :func:`_ukf_predict`
    with ``part = 1``, as :func:`filter_offline` applies it (see :func:`ekf_predict_step`)."""
    n, m = x.shape[0], u.shape[0]
    _ukf_predict(
        x, P, u, 1.0, dt, integ, M, K, floor, rate, cal, cidx, walk,
        Wm, Wc, c, angles, tol, _work(n, m), ukf_work(n, m), scale,
    )  # fmt: skip


@njit(cache=True)
def ukf_update_row(
    x, P, kind, z0, z1, a0, a1, r00, r01, r11, i0, i1, dt, gate, Wm, Wc, c, angles, tol, out
):  # fmt: skip
    """One gated update of the streaming UKF Localizer, in place: :func:`_ukf_update` on the
    row's values as :func:`ekf_update_row` takes them; ``out`` (5,) receives the innovation
    and its covariance; returns ``(nis, accepted)``."""
    z, aux, idx = _row_arrays(z0, z1, a0, a1, i0, i1)
    n = x.shape[0]
    return _ukf_update(
        x, P, kind, z, aux, r00, r01, r11, idx, dt, gate,
        Wm, Wc, c, angles, tol, _work(n, 1), ukf_work(n, 1), out,
    )  # fmt: skip


@njit(cache=True)
def odom_steps(odom, U, integ, M):
    """Compose the steps ``U`` (N, m) onto the continuous odometry pose ``odom`` (3,) in place,
    as :func:`ekf_offline` does after each step (the streaming Localizer's ``odom`` pose)."""
    m = U.shape[1]
    Jt = np.empty((3, 3))
    dummy = np.empty((3, m))
    var0 = np.empty(m)
    zero_P = np.zeros((3, 3))
    for k in range(U.shape[0]):
        w = vx = vy = 0.0
        for i in range(m):
            w += M[0, i] * U[k, i]
            vx += M[1, i] * U[k, i]
            vy += M[2, i] * U[k, i]
        d0, d1, d2 = _increment(integ, w, vx, vy, Jt)
        _pose_step(odom, d0, d1, d2, zero_P, dummy, var0, False)


# ----------------------------------------------------------------------- particle filter
@njit(cache=True)
def pf_predict(X, u, var, Z, integ, M, cal, C, cidx, dt, Zth, sd_th, dtheta, e, Zw, sd_w):
    """``ParticleBackend.predict`` of a drive with ``twist = M u``, in place on ``X`` (N, n).

    ``u`` (m,) is the step's input and ``var`` (m,) its variances (noise scale included);
    ``Z`` (N, m) the standard normals of the inputs, drawn by the backend's generator.
    ``cal``: 0 none, 1 increments (``cidx`` the ds scale, dtheta scale, heading bias columns),
    2 two wheels (``cidx`` ``E_d``, ``E_b`` and, when given, ``E_s``; ``C`` (2, 2) the track
    matrix); each particle's
    own calibration is read before it moves. ``Zth`` (N,) with ``sd_th >= 0``: a gyro heading
    change ``dtheta + Zth sd_th`` replaces the twist's (``Zth`` empty: none). ``e`` (N,), when
    not empty, receives each particle's heading noise of the step (the gyro's, or the twist's
    rotation minus that of the noiseless calibrated input). ``Zw`` (N, n - 3) with ``sd_w``:
    the random walk of the states after the pose (``Zw`` with no columns: none).
    """
    N = X.shape[0]
    m = u.shape[0]
    Jt = np.empty((3, 3))
    sd = np.empty(m)
    ui = np.empty(m)
    u0 = np.empty(m)
    for j in range(m):
        sd[j] = math.sqrt(var[j])
    gyro = Zth.shape[0] > 0
    want_e = e.shape[0] > 0
    nw = Zw.shape[1]
    for i in range(N):
        for j in range(m):
            ui[j] = u[j] + Z[i, j] * sd[j]
            u0[j] = u[j]
        if cal == 1:
            a, b, c = X[i, cidx[0]], X[i, cidx[1]], X[i, cidx[2]]
            ui[0], ui[1] = a * ui[0], b * ui[1] + c * dt
            u0[0], u0[1] = a * u0[0], b * u0[1] + c * dt
        elif cal == 2:
            E, Eb = X[i, cidx[0]], X[i, cidx[1]]
            fl, fr, k = 2.0 / (1.0 + E), 2.0 * E / (1.0 + E), 1.0 - 1.0 / Eb
            Es = X[i, cidx[2]] if cidx.shape[0] > 2 else 1.0  # wheel_radius_scale
            for v in (ui, u0):
                L, R = v[0] * fl, v[1] * fr
                v[0] = Es * (L + k * (C[0, 0] * L + C[0, 1] * R))
                v[1] = Es * (R + k * (C[1, 0] * L + C[1, 1] * R))
        w = vx = vy = 0.0
        for j in range(m):
            w += M[0, j] * ui[j]
            vx += M[1, j] * ui[j]
            vy += M[2, j] * ui[j]
        d0, d1, d2 = _increment(integ, w, vx, vy, Jt)
        if gyro:
            noise = Zth[i] * sd_th
            d2 = dtheta + noise
            if want_e:
                e[i] = noise
        elif want_e:
            w0 = 0.0
            for j in range(m):
                w0 += M[0, j] * u0[j]
            e[i] = w - w0
        th = X[i, 2]
        c, s = math.cos(th), math.sin(th)
        X[i, 0] += c * d0 - s * d1
        X[i, 1] += s * d0 + c * d1
        X[i, 2] = _wrap(th + d2)
        for k in range(nw):
            X[i, 3 + k] += Zw[i, k] * sd_w[k]


@njit(cache=True)
def pf_moments(E, w, y, S):
    """The cloud's innovation moments: ``y = w @ E`` (d,) and ``S = sum_i w_i D_i D_i^T``
    (d, d), ``D = E - y``, into ``y`` and ``S`` (``ParticleBackend.update`` adds ``R``)."""
    N, d = E.shape
    for a in range(d):
        acc = 0.0
        for i in range(N):
            acc += w[i] * E[i, a]
        y[a] = acc
    for a in range(d):
        for b in range(a, d):
            acc = 0.0
            for i in range(N):
                acc += w[i] * (E[i, a] - y[a]) * (E[i, b] - y[b])
            S[a, b] = acc
            S[b, a] = acc


@njit(cache=True)
def pf_reweight(C, Si, w, out):
    """Weights ``out`` (N,) ``∝ max(w, 1e-300) exp(-C_i^T Si C_i / 2)``, normalised (by the
    log-weights less their maximum); returns the effective sample size ``1 / sum out^2``."""
    N, d = C.shape
    top = -np.inf
    for i in range(N):
        q = 0.0
        for a in range(d):
            acc = 0.0
            for b in range(d):
                acc += Si[a, b] * C[i, b]
            q += C[i, a] * acc
        lw = math.log(max(w[i], 1e-300)) - 0.5 * q
        out[i] = lw
        if lw > top:
            top = lw
    total = 0.0
    for i in range(N):
        v = math.exp(out[i] - top)
        out[i] = v
        total += v
    sq = 0.0
    for i in range(N):
        v = out[i] / total
        out[i] = v
        sq += v * v
    return 1.0 / sq


@njit(cache=True)
def pf_mean(X, w, angles, m):
    """Weighted mean ``m`` (n,) of the cloud ``X`` (N, n), circular on the ``angles`` columns
    (``ParticleBackend.mean``)."""
    N, n = X.shape
    for k in range(n):
        acc = 0.0
        for i in range(N):
            acc += w[i] * X[i, k]
        m[k] = acc
    for k in angles:
        sa = ca = 0.0
        for i in range(N):
            sa += w[i] * math.sin(X[i, k])
            ca += w[i] * math.cos(X[i, k])
        m[k] = math.atan2(sa, ca)


@njit(cache=True)
def pf_gram(X, w, m, is_angle, G):
    """``G = sum_i w_i D_i D_i^T`` (n, n), ``D = X - m`` with the angle columns wrapped (the
    Gram matrix of :func:`odofuse.estimators.particle.weighted_cov`); returns ``sum w^2``."""
    N, n = X.shape
    D = np.empty((n, N))  # by state, so that each entry of G is a contiguous dot product
    for i in range(N):
        for a in range(n):
            v = X[i, a] - m[a]
            D[a, i] = _wrap(v) if is_angle[a] else v
    sq = 0.0
    for i in range(N):
        sq += w[i] * w[i]
    for a in range(n):
        Da = D[a]
        for b in range(a, n):
            Db = D[b]
            acc = 0.0
            for i in range(N):
                acc += w[i] * Da[i] * Db[i]
            G[a, b] = acc
            G[b, a] = acc
    return sq


@njit(cache=True)
def pf_cov(X, w, angles, is_angle, P):
    """``ParticleBackend.cov`` in one call: the mean (:func:`pf_mean`), the Gram matrix
    (:func:`pf_gram`) and ``particle._scaled_psd`` (its eigenvalues clipped at 0, over
    ``1 - sum w^2``; zeros for a single effective particle) into ``P`` (n, n)."""
    n = X.shape[1]
    m = np.empty(n)
    pf_mean(X, w, angles, m)
    G = np.empty((n, n))
    denom = 1.0 - pf_gram(X, w, m, is_angle, G)
    if not denom > 1e-12:
        P[:, :] = 0.0
        return
    vals, vecs = np.linalg.eigh(G)  # G is symmetric by construction
    for k in range(n):
        vals[k] = max(vals[k], 0.0) / denom
    for a in range(n):
        for b in range(a, n):
            acc = 0.0
            for k in range(n):
                acc += vecs[a, k] * vals[k] * vecs[b, k]
            P[a, b] = acc
            P[b, a] = acc


# ------------------------------------------------------------------- the on-disk cache's index
def _lock_cache_saves() -> bool:
    """Serialise numba's cache saves of these kernels across processes; whether it could.

    numba (0.68, ``caching.IndexDataCacheFile.save``) saves a new machine code by reading the
    function's index, taking the first free data-file number, writing the index and then the
    data, with no lock. Two processes that compile *different* signatures of one kernel at
    once (the EKF's and the UKF's ``filter_offline``: a background compile, :mod:`.warm`; two
    Dask workers or two test workers on a cold cache) can both read the old index and take
    the same number: one signature is lost from the index, and the data file may then hold
    the other signature's code under its name. Holding an exclusive ``flock`` on one file of
    the cache folder around each save makes the second process read the first one's index
    (``tests/test_compiled_warm.py``). Loads need no lock: numba replaces both files whole.
    """
    try:
        import fcntl

        from numba.core.registry import CPUDispatcher
    except ImportError:  # no flock (Windows): the background compile is then not started
        return False
    kernels = [v for v in globals().values() if isinstance(v, CPUDispatcher)]
    try:
        files = [k._cache._cache_file for k in kernels]
        for f in files:
            f.save = _locked(f.save, os.path.join(f._cache_path, "odofuse-kernels.lock"), fcntl)
    except AttributeError:  # another numba's cache layout: leave its saves as they are
        return False
    return True


def _locked(save, lock_path: str, fcntl):
    def save_locked(key, data):
        try:
            f = open(lock_path, "a")  # noqa: SIM115 - closed below, after the save
        except OSError:  # a folder numba can write to but not create files in: as before
            return save(key, data)
        with f:
            fcntl.flock(f, fcntl.LOCK_EX)  # released when f is closed
            return save(key, data)

    return save_locked


#: Whether two processes may compile these kernels at once (:func:`_lock_cache_saves`).
CACHE_SAVES_LOCKED = _lock_cache_saves()


# ------------------------------------------------------ one compile of a signature per machine
#: Seconds a process waits for another one's compile of the same signature before it compiles
#: it itself (a compile takes 1-20 s here; the wait only guards against a stuck process).
COMPILE_WAIT_S = 300.0


def _share_compiles() -> bool:
    """Compile each signature of these kernels in one process at a time, machine-wide; whether
    it could.

    numba compiles a kernel at its first call in every process whose on-disk cache has no
    machine code for it yet. On a fresh install, processes started together (the workers of
    ``odofuse batch``, of the test suite, a run and its background compile) then compile the
    same signature side by side, each for 1-20 s of a core, and only one copy is kept. With
    this, a process that misses the cache takes an exclusive ``flock`` named after the kernel
    and signature (a file in the cache folder) and looks again: if another process compiled
    that signature meanwhile, it loads it; else it compiles and saves it, then lets go.
    Different signatures (the EKF's and the UKF's ``filter_offline``: :mod:`.warm`) still
    compile at once. A kernel's callees are locked the same way inside its compile; they never
    call it back, so two processes cannot wait on each other.
    """
    try:
        import fcntl

        from numba.core.registry import CPUDispatcher
    except ImportError:
        return False
    kernels = [v for v in globals().values() if isinstance(v, CPUDispatcher)]
    try:
        for k in kernels:
            _compile_once(k, k._cache, k._cache._cache_file._cache_path, fcntl)
    except AttributeError:  # another numba's cache layout: every process compiles, as before
        return False
    return True


def _compile_once(kernel, cache, folder: str, fcntl) -> None:
    """Wrap ``kernel.compile`` and ``cache.load_overload`` (:func:`_share_compiles`)."""
    import hashlib
    import time

    load, compile_ = cache.load_overload, kernel.compile
    held: dict = {}  # signature -> the lock file this process compiles it under

    def lock(sig):
        digest = hashlib.sha1(str(sig).encode()).hexdigest()[:16]
        path = os.path.join(folder, f"odofuse-compile-{kernel.__name__}-{digest}.lock")
        try:
            os.makedirs(folder, exist_ok=True)
            f = open(path, "a")  # noqa: SIM115 - closed when the compile ends
        except OSError:  # a cache folder this process cannot write: compile as before
            return None
        deadline = time.monotonic() + COMPILE_WAIT_S
        while True:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return f
            except OSError:
                if time.monotonic() > deadline:
                    f.close()
                    return None
                time.sleep(0.05)

    def load_or_wait(sig, target_context):
        cres = load(sig, target_context)
        if cres is not None or sig in held:
            return cres
        f = lock(sig)
        if f is None:
            return None
        cres = load(sig, target_context)  # another process may have saved it meanwhile
        if cres is not None:
            f.close()
            return cres
        held[sig] = f  # this process compiles it: released once compile() returns
        return None

    def compile_once(sig):
        try:
            return compile_(sig)
        finally:
            f = held.pop(sig, None)
            if f is not None:
                f.close()

    cache.load_overload, kernel.compile = load_or_wait, compile_once


#: Whether each signature is compiled by one process at a time (:func:`_share_compiles`).
COMPILES_SHARED = _share_compiles()
