"""Unscented Kalman filter (filterpy) over the same motion function as the EKF.

Each sigma point of ``[x, y, theta, augmented...]`` is moved by the run's motion model:
``pose' = pose (+) delta(u)`` (the head-to-tail composition of ``002_88fc37db58155723.txt``
with the drive/integrator increment of :class:`~odofuse.motion.MotionModel`); augmented states
are constant. The odometry error model's input noise enters as the additive process noise
``Q = F_u Sigma_u F_u^T`` of the EKF (``Sigma_u`` from the wheel travel, Siegwart &
Nourbakhsh ch. 5, ``004_f4547100a083f338.txt``), plus the augmented states' random walk.

Angles are handled everywhere filterpy lets us: the state mean is circular in theta (and in
heading clones), state residuals and ``state_add`` wrap theta, and each sensor's
``residual``/``mean`` are installed as ``residual_z``/``z_mean`` before its update. After a
first update at a time stamp the sigma points are regenerated from the updated ``x``, ``P``
before a second update (filterpy would otherwise reuse the predicted ones).
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.declarations import UkfOptions
from odofuse.estimators.assembly import run_with
from odofuse.estimators.common import SINGULAR_PIVOT, angle_states
from odofuse.estimators.ekf import FastIncrement, increment_function
from odofuse.measurements import gate_threshold
from odofuse.options import coerce
from odofuse.se2 import wrap_angle


def _psd_sqrt(A: np.ndarray) -> np.ndarray:
    """Matrix ``U`` with ``U^T U = A`` for the sigma points: Cholesky, or for a singular ``A``
    (a heading clone right after cloning equals theta exactly) the symmetric square root
    from the eigen-decomposition with negative round-off eigenvalues clipped to zero.

    Singular means a pivot at or below :data:`SINGULAR_PIVOT` of its diagonal entry, not only
    the one LAPACK refuses: on an exact clone the last pivot is round-off of either sign, and
    taking LAPACK's Cholesky when it happened to come out positive (a fifth of the clones)
    made the run depend on the last bit of ``P`` (one ulp of ``A`` moved a figure-eight's
    poses by 2.6e-6 m; with this rule, by 1e-13 m).
    """
    import scipy.linalg

    try:
        U = scipy.linalg.cholesky(A)
        if np.all(np.square(np.diag(U)) > SINGULAR_PIVOT * np.diag(A)):
            return U
    except np.linalg.LinAlgError:
        pass
    vals, vecs = np.linalg.eigh(0.5 * (A + A.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T


class UkfBackend:
    """UKF backend for :class:`~odofuse.estimators.localizer.Localizer`.

    Parameters
    ----------
    model : MotionModel
    models : dict
        Stream -> bound measurement model.
    x0, P0 : ndarray (n,), (n, n)
    walk : ndarray (n,)
        Random-walk variance per second of each state.
    options : UkfOptions or dict, optional
        ``alpha``, ``beta``, ``kappa`` of Van der Merwe's scaled sigma points; a mapping is
        validated into :class:`UkfOptions`.
    """

    #: Odometry-calibration states (:mod:`odofuse.estimators.odocal`), set by ``assemble``.
    odo_cal = None

    def __init__(self, model, models, x0, P0, walk, options=None) -> None:
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

        options = coerce(UkfOptions, options, "options.ukf")
        n = len(x0)
        self.model = model
        self.n = n
        self.walk = np.asarray(walk, dtype=float)
        self.angles = angle_states(models)
        points = MerweScaledSigmaPoints(
            n,
            alpha=options.alpha,
            beta=options.beta,
            kappa=options.kappa,
            subtract=self.residual_x,
            sqrt_method=_psd_sqrt,
        )
        self.points = points
        self.kf = UnscentedKalmanFilter(
            dim_x=n,
            dim_z=1,
            dt=1.0,
            hx=None,
            fx=self._fx,
            points=points,
            x_mean_fn=self.x_mean,
            residual_x=self.residual_x,
            state_add=self.state_add,
        )
        self.kf.x = np.array(x0, dtype=float)
        self.kf.P = np.array(P0, dtype=float)
        self._fresh = False  # sigmas_f hold the points of the last predict
        self._gates = {
            id(m): gate_threshold(getattr(m, "gate", None), m.dim) for m in models.values()
        }
        fast = FastIncrement(model)
        self._fast = fast if fast.ok else None
        self.increment = increment_function(model, fast)  # MotionModel.increment, faster

    # -- angle-aware state arithmetic ---------------------------------------------------
    def residual_x(self, a, b) -> np.ndarray:
        d = np.subtract(a, b)
        for i in self.angles:  # filterpy calls it for every sigma point: scalar wraps
            d[i] = wrap_angle(d.item(i))
        return d

    def state_add(self, x, dx) -> np.ndarray:
        s = np.add(x, dx)
        for i in self.angles:
            s[i] = wrap_angle(s.item(i))
        return s

    def x_mean(self, sigmas, Wm) -> np.ndarray:
        m = Wm @ sigmas
        for i in self.angles:
            m[i] = math.atan2(Wm @ np.sin(sigmas[:, i]), Wm @ np.cos(sigmas[:, i]))
        return m

    # -- motion -----------------------------------------------------------------------------
    def _fx(self, s, dt, delta=None, raw=None):
        if raw is not None:
            u, step, dtheta = raw
            cal = self.odo_cal
            delta, _ = self.increment(cal.apply(u, s[list(cal.index)], step))
            if dtheta is not None:
                delta = delta.copy()
                delta[2] = dtheta
        c, sn = math.cos(s[2]), math.sin(s[2])
        out = s.copy()
        out[0] = s[0] + c * delta[0] - sn * delta[1]
        out[1] = s[1] + sn * delta[0] + c * delta[1]
        out[2] = wrap_angle(s[2] + delta[2])
        return out

    def predict(
        self,
        u,
        dt: float,
        dtheta: float | None = None,
        var_dtheta: float = 0.0,
        noise_scale: float = 1.0,
    ) -> None:
        """Sigma points through ``pose (+) delta(u)``; additive ``Q = F_u Sigma_u F_u^T``.

        ``noise_scale`` multiplies ``Sigma_u`` (robust odometry during wheel slip).
        """
        cal = self.odo_cal
        raw = np.asarray(u, dtype=float)
        if cal is not None:  # the noise at the calibrated input of the mean
            u = cal.apply(u, self.kf.x[list(cal.index)], dt)
        if self._fast is not None:
            delta, J, var = self._fast(np.asarray(u, dtype=float), dt)
        else:
            delta, J = self.model.increment(u)
            var = self.model.errors.variances(self.model.drive, u, dt)
        var = var * noise_scale
        if dtheta is not None:
            delta, J = delta.copy(), J.copy()
            delta[2] = dtheta
            J[2, :] = 0.0
        th = self.kf.x[2]
        c, s = math.cos(th), math.sin(th)
        J_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        F_u = J_b @ J
        Q = np.zeros((self.n, self.n))
        Q[:3, :3] = (F_u * var) @ F_u.T
        Q[2, 2] += var_dtheta if dtheta is not None else 0.0
        if dt > 0:
            Q[np.diag_indices(self.n)] += self.walk * dt
        self.kf.Q = Q
        if cal is None:
            self.kf.predict(dt=dt, delta=delta)
        else:  # each sigma point moves by the increment of its own calibration
            self.kf.predict(dt=dt, delta=None, raw=(raw, dt, None if dtheta is None else dtheta))
        self.kf.P = 0.5 * (self.kf.P + self.kf.P.T)
        self._fresh = True

    # -- update -----------------------------------------------------------------------------
    def update(self, model, row) -> tuple[bool, float]:
        """Gated filterpy UKF update with the sensor's own residual and mean."""
        kf = self.kf
        if not self._fresh:
            kf.sigmas_f = self.points.sigma_points(kf.x, kf.P)
        x0, P0, sig0 = kf.x.copy(), kf.P.copy(), kf.sigmas_f.copy()
        kf.residual_z = model.residual
        kf.z_mean = model.mean
        kf._dim_z = model.dim
        R = model.R(row)
        kf.update(model.z(row), R=R, hx=lambda s: model.h(s, row))
        y = kf.y
        nis = float(y @ kf.SI @ y)
        self.last_innovation = (y.copy(), kf.S.copy(), R)
        gate = self._gates.get(id(model))
        if gate is None:
            gate = self._gates[id(model)] = gate_threshold(getattr(model, "gate", None), model.dim)
        if not nis <= gate:
            kf.x, kf.P, kf.sigmas_f = x0, P0, sig0
            return False, nis
        kf.P = 0.5 * (kf.P + kf.P.T)
        self._fresh = False
        return True, nis

    # -- bookkeeping ------------------------------------------------------------------------
    def clone(self, dst: int, src: int) -> None:
        x, P = self.kf.x.copy(), self.kf.P.copy()
        x[dst] = x[src]
        P[dst, :] = P[src, :]
        P[:, dst] = P[:, src]
        P[dst, dst] = P[src, src]
        self.kf.x, self.kf.P = x, P
        self._fresh = False

    def inflate(self, factor: float, idx) -> None:
        """Scale the covariance of states ``idx`` by ``factor`` (``P <- D P D``, SPD kept)."""
        D = np.ones(self.n)
        D[list(idx)] = math.sqrt(factor)
        self.kf.P = D[:, None] * self.kf.P * D[None, :]
        self._fresh = False

    def snapshot(self):
        return self.kf.x.copy(), self.kf.P.copy(), self.kf.sigmas_f.copy(), self._fresh

    def restore(self, snap) -> None:
        x, P, sig, fresh = snap
        self.kf.x, self.kf.P, self.kf.sigmas_f, self._fresh = x.copy(), P.copy(), sig.copy(), fresh

    def mean(self) -> np.ndarray:
        return self.kf.x

    def cov(self) -> np.ndarray:
        return self.kf.P


def make_backend(model, models, x0, P0, walk, options) -> UkfBackend:
    """Backend factory for :func:`odofuse.estimators.assembly.build`."""
    return UkfBackend(model, models, x0, P0, walk, options)


def run(log, config):
    """UKF over a whole log: the compiled core when it covers the run (``options.ukf.compiled``,
    :mod:`odofuse.estimators.compiled.ukf`), else a thin wrapper feeding the log to a
    streaming Localizer."""
    from odofuse.estimators.compiled import ukf as compiled_ukf

    result = compiled_ukf.run(log, config)  # numba core, None when not covered or off
    return result if result is not None else run_with(log, config, "ukf", make_backend)


def live(loc) -> None:
    """Give a live UKF Localizer (``Localizer.from_config``) the compiled core's step kernels
    when ``odofuse run`` would use that core, so that online equals offline bit for bit
    (:func:`odofuse.estimators.compiled.ukf.live`)."""
    from odofuse.estimators.compiled import ukf as compiled_ukf

    compiled_ukf.live(loc)
