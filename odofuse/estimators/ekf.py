"""Extended Kalman filter (filterpy) with the drive + integrator + odometry error model.

The prediction is not a generic constant-velocity model: it is the run's
:class:`~odofuse.motion.MotionModel` (Siegwart & Nourbakhsh ch. 5, ``004_f4547100a083f338.txt``)::

    x' = x (+) delta(u),   P' = F_p P F_p^T + F_u Sigma_u F_u^T

with the analytic ``F_p`` (``se2.J_compose``) and ``F_u = J_b J_delta_u``, and ``Sigma_u``
from the wheel travel (``k_i |ds_i|``). filterpy's ``ExtendedKalmanFilter.predict`` is linear
(``F x + B u``), so the filter's ``x``/``P`` are set here and only its ``update`` is used
(Joseph form, ``P = (I-KH)P(I-KH)^T + KRK^T``, which stays symmetric positive definite even
with a sub-optimal gain). Its update adds with ``+``, so theta is wrapped afterwards.

Augmented states (range scale/offset, gyro bias, compass offset, gyro heading clone) follow
the pose; they are constant in the prediction apart from a random walk of variance
``walk_i * dt``.

Gating: the normalised innovation squared ``y^T S^-1 y`` of each update is compared with the
sensor's chi-square bound (``gate``); a rejected update is undone (the pre-update ``x``, ``P``
are restored) and counted.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.estimators.assembly import run_with
from odofuse.measurements import gate_threshold
from odofuse.motion import linear_terms

TWO_PI = 2.0 * math.pi
_SERIES_BELOW = 1e-2


def _exp_coeffs(w: float) -> tuple[float, float, float, float]:
    """Scalar ``A = sin w / w``, ``B = (1 - cos w) / w`` and their derivatives.

    The same half-angle forms and Taylor series as ``se2._exp_coefficients`` (which works on
    arrays and costs ~10x more per call on one twist).
    """
    half = 0.5 * w
    sh, ch = math.sin(half), math.cos(half)
    sinc_half = 1.0 if half == 0.0 else sh / half  # half underflows for subnormal w
    A, B = sinc_half * ch, sinc_half * sh
    if abs(w) < _SERIES_BELOW:
        w2 = w * w
        dA = w * (-1.0 / 3.0 + w2 * (1.0 / 30.0 + w2 * (-1.0 / 840.0 + w2 / 45360.0)))
        dB = 0.5 + w2 * (-1.0 / 8.0 + w2 * (1.0 / 144.0 + w2 * (-1.0 / 5760.0 + w2 / 403200.0)))
    else:
        s, omc = 2.0 * sh * ch, 2.0 * sh * sh
        dA = (w * (1.0 - omc) - s) / (w * w)
        dB = (w * s - omc) / (w * w)
    return A, B, dA, dB


class FastIncrement:
    """Scalar-math ``MotionModel.increment`` + ``input_cov`` for drives with ``twist = F u``.

    Only a speed-up: at construction it is checked against the model's own ``increment`` and
    error variances on a few inputs, and :attr:`ok` is False (callers fall back to the
    model) if they differ by more than 1e-12.
    """

    def __init__(self, model) -> None:
        drive = model.drive
        self.ok = False
        terms = linear_terms(model)
        if terms is None:
            return
        self.M, self.K, self.floor, self.rate = terms
        self.integrator = model.integrator
        self._K = self.K.tolist()
        self._f = self.floor.tolist()
        self._r = self.rate.tolist()
        self._Ml = self.M.tolist()
        self._two = self.M.shape[1] == 2
        rng = np.random.default_rng(0)
        n = self.M.shape[1]
        try:
            for u in (np.zeros(n), rng.normal(0, 0.1, n), rng.normal(0, 1e-4, n)):
                d, J, var = self(u)
                *dt, G = self.terms(u)
                d0, J0 = model.increment(u)
                var0 = model.errors.variances(drive, u)
                if not (
                    np.allclose(d, d0, rtol=0, atol=1e-12)
                    and np.allclose(dt, d0, rtol=0, atol=1e-12)
                    and np.allclose(J, J0, rtol=0, atol=1e-12)
                    and np.allclose(G, J0 * np.sqrt(var0), rtol=0, atol=1e-12)
                    and np.allclose(var, var0, rtol=1e-12, atol=1e-15)
                ):
                    return
        except Exception:  # noqa: BLE001 - any mismatch just disables the fast path
            return
        self.ok = True

    def _increment(self, w: float, vx: float, vy: float):
        """Scalar ``delta`` and ``J_delta_twist`` (3 x 3 tuples) of the model's integrator."""
        if self.integrator == "exact":
            A, B, dA, dB = _exp_coeffs(w)
            d = (A * vx - B * vy, B * vx + A * vy, w)
            Jt = ((dA * vx - dB * vy, A, -B), (dB * vx + dA * vy, B, A))
        elif self.integrator == "rk2":
            c, s = math.cos(0.5 * w), math.sin(0.5 * w)
            d = (c * vx - s * vy, s * vx + c * vy, w)
            Jt = ((0.5 * (-s * vx - c * vy), c, -s), (0.5 * (c * vx - s * vy), s, c))
        else:
            d = (vx, vy, w)
            Jt = ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        return d, Jt + ((1.0, 0.0, 0.0),)

    def __call__(self, u, dt: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(delta (3,), J_delta_u (3, n), var_u (n,))`` of one step of ``dt`` seconds."""
        d, J = self.increment(u)
        return d, J, self.K @ np.abs(u) + self.floor + self.rate * dt

    def increment(self, u) -> tuple[np.ndarray, np.ndarray]:
        """``MotionModel.increment(u)``: ``(delta (3,), J_delta_u (3, n))``."""
        d, Jt = self._increment(*(self.M @ np.asarray(u, dtype=float)).tolist())
        return np.array(d), np.array(Jt) @ self.M

    def terms(self, u, dt: float = 0.0) -> tuple[float, float, float, list[list[float]]]:
        """Scalar form for the EKF: ``delta`` as floats and ``G = J_delta_u diag(sigma_u)``.

        ``G G^T = J_delta_u Sigma_u J_delta_u^T`` is the body-frame process noise of the step.
        """
        ul = u.tolist()
        if self._two:
            (m00, m01), (m10, m11), (m20, m21) = self._Ml
            u0, u1 = ul
            w, vx, vy = m00 * u0 + m01 * u1, m10 * u0 + m11 * u1, m20 * u0 + m21 * u1
        else:
            w, vx, vy = (self.M @ u).tolist()
        d, Jt = self._increment(w, vx, vy)
        if self._two:
            # Two inputs (increments, differential, skid-steer): unrolled.
            (k00, k01), (k10, k11) = self._K
            f0, f1 = self._f
            r0, r1 = self._r
            a0, a1 = abs(u0), abs(u1)
            s0 = math.sqrt(k00 * a0 + k01 * a1 + f0 + r0 * dt)
            s1 = math.sqrt(k10 * a0 + k11 * a1 + f1 + r1 * dt)
            (r0, r1, r2), (p0, p1, p2), _ = Jt
            G = [
                [(r0 * m00 + r1 * m10 + r2 * m20) * s0, (r0 * m01 + r1 * m11 + r2 * m21) * s1],
                [(p0 * m00 + p1 * m10 + p2 * m20) * s0, (p0 * m01 + p1 * m11 + p2 * m21) * s1],
                [m00 * s0, m01 * s1],  # the theta row of J_delta_twist is (1, 0, 0)
            ]
            return d[0], d[1], d[2], G
        au = [abs(v) for v in ul]
        sd = [
            math.sqrt(sum(k * a for k, a in zip(row, au, strict=True)) + f + r * dt)
            for row, f, r in zip(self._K, self._f, self._r, strict=True)
        ]
        M = self._Ml
        G = [
            [(r[0] * M[0][j] + r[1] * M[1][j] + r[2] * M[2][j]) * sd[j] for j in range(len(sd))]
            for r in Jt
        ]
        return d[0], d[1], d[2], G


def increment_function(model, fast: FastIncrement | None = None):
    """``model.increment``, through ``fast`` (built here when None) where it applies."""
    fast = FastIncrement(model) if fast is None else fast
    return fast.increment if fast.ok else model.increment


class EkfBackend:
    """EKF state ``x`` (n,) = ``[x, y, theta, augmented...]`` and covariance ``P`` (n, n).

    Parameters
    ----------
    model : MotionModel
    models : dict
        Stream -> bound measurement model.
    x0 : ndarray (n,)
    P0 : ndarray (n, n)
    walk : ndarray (n,)
        Random-walk variance per second of each state (0 for the pose block).
    """

    #: Odometry-calibration states (:mod:`odofuse.estimators.odocal`), set by ``assemble``.
    odo_cal = None

    def __init__(self, model, models, x0, P0, walk, options=None) -> None:
        from filterpy.kalman import ExtendedKalmanFilter

        n = len(x0)
        self.model = model
        self.n = n
        self.kf = ExtendedKalmanFilter(dim_x=n, dim_z=1)
        self.kf.x = np.array(x0, dtype=float)
        self.kf.P = np.array(P0, dtype=float)
        self.walk = np.asarray(walk, dtype=float)
        self._has_walk = bool(np.any(self.walk > 0))
        self._gates = {}
        for m in models.values():
            self._gates[id(m)] = gate_threshold(getattr(m, "gate", None), m.dim)
        self._drive = model.drive
        self._errors = model.errors
        fast = FastIncrement(model)
        self._fast = fast if fast.ok else None
        self.increment = increment_function(model, fast)
        self._cvec = np.zeros(n)
        self._diag = np.diag_indices(n)

    # -- prediction ---------------------------------------------------------------
    def predict(
        self,
        u,
        dt: float,
        dtheta: float | None = None,
        var_dtheta: float = 0.0,
        noise_scale: float = 1.0,
    ) -> None:
        """Propagate through the motion model with input ``u`` over ``dt`` seconds.

        ``dtheta`` (gyrodometry) replaces the step's heading change, with variance
        ``var_dtheta`` instead of the wheels' contribution to it. ``noise_scale`` multiplies
        the wheel input variances of the step (robust odometry during wheel slip).
        """
        if self.odo_cal is not None:
            self._predict_calibrated(u, dt, dtheta, var_dtheta, noise_scale)
            return
        x, P = self.kf.x, self.kf.P
        if self._fast is not None:
            d0, d1, d2, G = self._fast.terms(u, dt)
        else:
            delta, J = self.model.increment(u)
            var = self._errors.variances(self._drive, u, dt)
            d0, d1, d2 = delta.tolist()
            G = (J * np.sqrt(var)).tolist()
        if noise_scale != 1.0:
            r = math.sqrt(noise_scale)
            G = [[g * r for g in row] for row in G]
        if dtheta is not None:
            d2 = float(dtheta)
            G = [G[0], G[1], [0.0] * len(G[2])]
        # Head-to-tail composition and its Jacobians (se2.compose / se2.J_compose, 002 source),
        # in scalar form: this is the hot path of the filter. F_u Sigma_u F_u^T = W W^T with
        # W = blockdiag(R(theta), 1) G.
        th = float(x[2])
        c, s = math.cos(th), math.sin(th)
        dxw = c * d0 - s * d1
        dyw = s * d0 + c * d1
        g0, g1, g2 = G
        if len(g2) == 2:  # unrolled for two inputs
            a0, a1 = c * g0[0] - s * g1[0], c * g0[1] - s * g1[1]
            b0, b1 = s * g0[0] + c * g1[0], s * g0[1] + c * g1[1]
            e0, e1 = g2
            q00, q01, q02 = a0 * a0 + a1 * a1, a0 * b0 + a1 * b1, a0 * e0 + a1 * e1
            q11, q12, q22 = b0 * b0 + b1 * b1, b0 * e0 + b1 * e1, e0 * e0 + e1 * e1
        else:
            w0 = [c * a - s * b for a, b in zip(g0, g1, strict=True)]
            w1 = [s * a + c * b for a, b in zip(g0, g1, strict=True)]
            q00 = sum(a * a for a in w0)
            q01 = sum(a * b for a, b in zip(w0, w1, strict=True))
            q02 = sum(a * b for a, b in zip(w0, g2, strict=True))
            q11 = sum(a * a for a in w1)
            q12 = sum(a * b for a, b in zip(w1, g2, strict=True))
            q22 = sum(a * a for a in g2)
        if dtheta is not None:
            q22 += var_dtheta
        xn = x.copy()
        xn[0] += dxw
        xn[1] += dyw
        xn[2] = (th + d2 + math.pi) % TWO_PI - math.pi
        # F_p = I + c e_theta^T with c = (-dy_w, dx_w, 0, ...) (Siegwart's F_p, extended by the
        # identity on augmented states), so F_p P F_p^T = P + B + B^T with B = c v^T and
        # v = P[theta, :] + P_tt c / 2. Every term is exactly symmetric, and it costs one
        # outer product instead of two n x n matrix products.
        cvec = self._cvec
        cvec[0], cvec[1] = -dyw, dxw
        B = cvec[:, None] * (P[2] + (0.5 * P[2, 2]) * cvec)  # outer product c v^T
        Pn = P + (B + B.T)
        # + Q on the pose block, element by element (cheaper than a 3x3 array here)
        Pn[0, 0] += q00
        Pn[1, 1] += q11
        Pn[2, 2] += q22
        v = Pn[0, 1] + q01
        Pn[0, 1] = Pn[1, 0] = v
        v = Pn[0, 2] + q02
        Pn[0, 2] = Pn[2, 0] = v
        v = Pn[1, 2] + q12
        Pn[1, 2] = Pn[2, 1] = v
        if self._has_walk and dt > 0:
            Pn[self._diag] += self.walk * dt
        self.kf.x = xn
        self.kf.P = Pn

    def transition(self, x, u, dt, dtheta=None):
        """Predicted state and its Jacobian ``F`` ``(n, n)`` with odometry calibration.

        ``u' = odo_cal.apply(u, p, dt)`` with ``p`` the calibration states of ``x``; the pose
        moves by ``delta(u')`` and ``F = [[F_p, F_u du'/dp], [0, I]]``. Also returns ``F_u``
        (3, n) for the process noise. ``dtheta`` replaces the heading change (gyrodometry).
        """
        cal = self.odo_cal
        idx = list(cal.index)
        p = x[idx]
        uc = cal.apply(u, p, dt)
        delta, J = self.increment(uc)
        if dtheta is not None:
            delta, J = delta.copy(), J.copy()
            delta[2], J[2, :] = dtheta, 0.0
        # se2.compose / se2.J_compose in scalar form (the filter's hot path)
        c, s = math.cos(x[2]), math.sin(x[2])
        dxw, dyw = c * delta[0] - s * delta[1], s * delta[0] + c * delta[1]
        J_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        F_u = J_b @ J
        F = np.eye(self.n)
        F[0, 2], F[1, 2] = -dyw, dxw
        F[:3, idx] = F_u @ cal.jacobian(u, p, dt)
        xn = x.copy()
        xn[0] += dxw
        xn[1] += dyw
        xn[2] = (x[2] + delta[2] + math.pi) % TWO_PI - math.pi
        return xn, F, F_u, uc

    def _predict_calibrated(self, u, dt, dtheta, var_dtheta, noise_scale) -> None:
        """General-matrix prediction with odometry-calibration states (:meth:`transition`)."""
        x, P = self.kf.x, self.kf.P
        xn, F, F_u, uc = self.transition(x, np.asarray(u, dtype=float), dt, dtheta)
        if self._fast is not None:
            var = self._fast(uc, dt)[2] * noise_scale
        else:
            var = self._errors.variances(self._drive, uc, dt) * noise_scale
        Pn = F @ P @ F.T
        Pn[:3, :3] += (F_u * var) @ F_u.T
        if dtheta is not None:
            Pn[2, 2] += var_dtheta
        if self._has_walk and dt > 0:
            Pn[self._diag] += self.walk * dt
        self.kf.x = xn
        self.kf.P = 0.5 * (Pn + Pn.T)

    # -- update ---------------------------------------------------------------------
    def update(self, model, row) -> tuple[bool, float]:
        """Gated filterpy update with ``model`` on one row; returns (accepted, NIS)."""
        kf = self.kf
        x0, P0 = kf.x, kf.P  # filterpy rebinds x and P, so these stay the prior
        # Models without angle rows subtract plainly (filterpy's default, cheaper).
        residual = model.residual if getattr(model, "angle_rows", (0,)) else np.subtract
        R = model.R(row)
        kf.update(
            model.z(row),
            model.H,
            model.h,
            R=R,
            args=(row,),
            hx_args=(row,),
            residual=residual,
        )
        y = kf.y
        nis = float(y.dot(kf.SI.dot(y)))
        self.last_innovation = (y, kf.S, R)
        gate = self._gates.get(id(model))
        if gate is None:
            gate = gate_threshold(getattr(model, "gate", None), model.dim)
            self._gates[id(model)] = gate
        if not nis <= gate:
            kf.x, kf.P = x0, P0
            return False, nis
        x = kf.x
        x[2] = (x[2] + math.pi) % TWO_PI - math.pi
        return True, nis

    # -- bookkeeping ------------------------------------------------------------------
    def clone(self, dst: int, src: int) -> None:
        """Stochastic cloning: state ``dst`` becomes a copy of state ``src`` (x and P)."""
        x, P = self.kf.x.copy(), self.kf.P.copy()
        x[dst] = x[src]
        P[dst, :] = P[src, :]
        P[:, dst] = P[:, src]
        P[dst, dst] = P[src, src]
        self.kf.x, self.kf.P = x, P

    def inflate(self, factor: float, idx) -> None:
        """Scale the covariance of states ``idx`` by ``factor`` (``P <- D P D``, SPD kept)."""
        D = np.ones(self.n)
        D[list(idx)] = math.sqrt(factor)
        self.kf.P = D[:, None] * self.kf.P * D[None, :]

    def snapshot(self):
        return self.kf.x.copy(), self.kf.P.copy()

    def restore(self, snap) -> None:
        self.kf.x, self.kf.P = snap[0].copy(), snap[1].copy()

    def mean(self) -> np.ndarray:
        return self.kf.x

    def cov(self) -> np.ndarray:
        return self.kf.P


def make_backend(model, models, x0, P0, walk, options) -> EkfBackend:
    """Backend factory for :func:`odofuse.estimators.assembly.build`."""
    return EkfBackend(model, models, x0, P0, walk, options)


def run(log, config):
    """EKF over a whole log: a thin wrapper feeding the log to a streaming Localizer.

    Returns
    -------
    EstimateResult
        One pose per odometry step (plus the initial one) with world-frame covariances;
        ``used``/``rejected`` per sensor; ``extra["calibration"]`` the final augmented states.
    """
    from odofuse.estimators.compiled import ekf as compiled_ekf

    result = compiled_ekf.run(log, config)  # numba core, None when not covered or off
    return result if result is not None else run_with(log, config, "ekf", make_backend)


def live(loc) -> None:
    """Give a live EKF Localizer (``Localizer.from_config``) the compiled core's step kernels
    when ``odofuse run`` would use that core, so that online equals offline bit for bit
    (:func:`odofuse.estimators.compiled.ekf.live`)."""
    from odofuse.estimators.compiled import ekf as compiled_ekf

    compiled_ekf.live(loc)
