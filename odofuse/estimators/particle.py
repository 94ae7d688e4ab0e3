"""Particle filter sampling from the odometry motion model, with low-variance resampling.

Prediction samples each particle's drive input from the odometry error model of the run's
:class:`~odofuse.motion.MotionModel`: ``u_i = u + e_i``, ``e_i ~ N(0, Sigma_u)`` with
``Sigma_u = diag(k_i |travel_i| + floor_i)`` (Siegwart & Nourbakhsh ch. 5,
``004_f4547100a083f338.txt``), then moves it by ``pose_i (+) delta(u_i)`` (head-to-tail,
``002_88fc37db58155723.txt``). This is the "sampling from the odometry motion model" idea of
Thrun's MCL, but with the Siegwart variances (on variances, per metre travelled), not
Thrun's ``alpha_1..4`` rotation/translation parameters.

Augmented states (range scale/offset, biases) are carried per particle: drawn from their
prior, moved by their random walk, and regularised at each resampling with the kernel
shrinkage of Liu & West (2001): ``z_i <- a z_i + (1 - a) m + N(0, h^2 V)`` with the weighted
mean ``m`` and covariance ``V`` before resampling, ``h = roughening`` (default 0.1) and
``a = sqrt(1 - h^2)``, which keeps ``m`` and ``V`` while spreading duplicated particles.

Update: weights multiply by the Gaussian likelihood of each particle's innovation (angle rows
wrapped). Gating uses the cloud's own innovation statistics: ``y = z - mean(h)``,
``S = cov(h) + R``, rejected when ``y^T S^-1 y`` exceeds the sensor's chi-square bound.
Resampling is low-variance (systematic: one uniform draw, N evenly spaced pointers, Thrun
"Probabilistic Robotics" table 4.4) when the effective sample size drops below
``resample_threshold * N``. All randomness comes from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.declarations import ParticleOptions
from odofuse.estimators.localizer import run_with
from odofuse.measurements import gate_threshold
from odofuse.options import coerce
from odofuse.se2 import wrap


def low_variance_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by low-variance (systematic) resampling.

    Parameters
    ----------
    weights : ndarray (N,)
        Normalised weights (sum 1).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray (N,) of int
        Particle ``i`` is copied ``floor(N w_i)`` or ``ceil(N w_i)`` times.
    """
    n = weights.size
    pointers = (rng.uniform(0.0, 1.0) + np.arange(n)) / n
    cum = np.cumsum(weights)
    cum[-1] = 1.0
    return np.searchsorted(cum, pointers, side="right").clip(max=n - 1)


class ParticleBackend:
    """Particle cloud ``X`` (N, n) with weights ``w`` (N,).

    Parameters
    ----------
    model : MotionModel
    models : dict
        Stream -> bound measurement model.
    x0, P0 : ndarray (n,), (n, n)
        Gaussian prior the particles are drawn from.
    walk : ndarray (n,)
        Random-walk variance per second of each state.
    options : ParticleOptions or dict, optional
        ``particles``, ``seed``, ``resample_threshold``, ``roughening`` (the Liu-West kernel
        width ``h``); a mapping is validated into :class:`ParticleOptions`.
    """

    def __init__(self, model, models, x0, P0, walk, options=None) -> None:
        options = coerce(ParticleOptions, options, "options.particle")
        self.model = model
        self.N = options.particles
        self.rng = np.random.default_rng(options.seed)
        self.resample_threshold = options.resample_threshold
        self.roughening = options.roughening
        x0 = np.asarray(x0, dtype=float)
        self.n = x0.size
        self.walk = np.asarray(walk, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        # Draw from N(x0, P0); P0 may be singular (clone states): use an eigen square root.
        vals, vecs = np.linalg.eigh(0.5 * (P0 + P0.T))
        root = vecs * np.sqrt(np.clip(vals, 0.0, None))
        self.X = x0 + self.rng.standard_normal((self.N, self.n)) @ root.T
        self.X[:, 2] = wrap(self.X[:, 2])
        self.w = np.full(self.N, 1.0 / self.N)
        self.angles = [2]
        for m in models.values():
            idx = getattr(m, "calib_index", {})
            for s in m.clones() if hasattr(m, "clones") else {}:
                if s in idx:
                    self.angles.append(idx[s])
                    self.X[:, idx[s]] = self.X[:, 2]
        clone_cols = set(self.angles[1:])
        self._kernel_cols = [i for i in range(3, self.n) if i not in clone_cols]
        self._gates = {
            id(m): gate_threshold(getattr(m, "gate", None), m.dim) for m in models.values()
        }
        self.resamples = 0

    # -- motion -----------------------------------------------------------------------------
    def increment(self, u):
        return self.model.increment(u)

    def predict(self, u, dt: float, dtheta: float | None = None, var_dtheta: float = 0.0) -> None:
        """Sample every particle's input from the error model and move it."""
        u = np.asarray(u, dtype=float)
        var = self.model.errors.variances(self.model.drive, u)
        U = u + self.rng.standard_normal((self.N, u.size)) * np.sqrt(var)
        delta, _ = self.model.increment(U)
        if dtheta is not None:
            delta = delta.copy()
            delta[:, 2] = dtheta + self.rng.standard_normal(self.N) * math.sqrt(var_dtheta)
        X = self.X
        c, s = np.cos(X[:, 2]), np.sin(X[:, 2])
        X[:, 0] += c * delta[:, 0] - s * delta[:, 1]
        X[:, 1] += s * delta[:, 0] + c * delta[:, 1]
        X[:, 2] = wrap(X[:, 2] + delta[:, 2])
        if dt > 0 and self.n > 3:
            sd = np.sqrt(self.walk[3:] * dt)
            if np.any(sd > 0):
                X[:, 3:] += self.rng.standard_normal((self.N, self.n - 3)) * sd

    # -- update -----------------------------------------------------------------------------
    def _h(self, model, row) -> np.ndarray:
        if hasattr(model, "h_many"):
            return np.asarray(model.h_many(self.X, row), dtype=float).reshape(self.N, model.dim)
        return np.array([model.h(x, row) for x in self.X]).reshape(self.N, model.dim)

    def update(self, model, row) -> tuple[bool, float]:
        """Reweight by the sensor likelihood (gated on the cloud's NIS); resample if needed."""
        z = np.asarray(model.z(row), dtype=float)
        Z = self._h(model, row)
        R = np.asarray(model.R(row), dtype=float)
        rows = list(getattr(model, "angle_rows", ()))
        E = z - Z
        if rows:
            E[:, rows] = wrap(E[:, rows])
        w = self.w
        y = w @ E  # mean innovation (angles: residuals are already small and unwrapped)
        D = E - y
        S = (D * w[:, None]).T @ D + R
        Si = np.linalg.inv(S)
        nis = float(y @ Si @ y)
        gate = self._gates.get(id(model))
        if gate is None:
            gate = self._gates[id(model)] = gate_threshold(getattr(model, "gate", None), model.dim)
        if not nis <= gate:
            return False, nis
        Ri = np.linalg.inv(R)
        logl = -0.5 * np.einsum("ni,ij,nj->n", E, Ri, E)
        logw = np.log(np.maximum(w, 1e-300)) + logl
        logw -= logw.max()
        w = np.exp(logw)
        self.w = w / w.sum()
        if 1.0 / np.sum(self.w**2) < self.resample_threshold * self.N:
            self._resample()
        return True, nis

    def _resample(self) -> None:
        cols = self._kernel_cols
        if cols and self.roughening > 0:
            # Liu & West kernel shrinkage for the (static) augmented states: the weighted
            # posterior mean m and covariance V are kept, while duplicated particles are spread
            # again, so resampling alone does not collapse a constant parameter onto one value.
            Z = self.X[:, cols]
            m = self.w @ Z
            D = Z - m
            V = (D * self.w[:, None]).T @ D
        idx = low_variance_resample(self.w, self.rng)
        self.X = self.X[idx]
        self.w = np.full(self.N, 1.0 / self.N)
        self.resamples += 1
        if cols and self.roughening > 0:
            h2 = self.roughening**2
            a = math.sqrt(1.0 - h2)
            vals, vecs = np.linalg.eigh(0.5 * (V + V.T))
            root = vecs * np.sqrt(np.clip(vals, 0.0, None) * h2)
            noise = self.rng.standard_normal((self.N, len(cols))) @ root.T
            self.X[:, cols] = a * self.X[:, cols] + (1.0 - a) * m + noise

    # -- bookkeeping ------------------------------------------------------------------------
    def clone(self, dst: int, src: int) -> None:
        self.X[:, dst] = self.X[:, src]

    def snapshot(self):
        return self.X.copy(), self.w.copy(), self.rng.bit_generator.state, self.resamples

    def restore(self, snap) -> None:
        X, w, state, resamples = snap
        self.X, self.w = X.copy(), w.copy()
        self.rng.bit_generator.state = state
        self.resamples = resamples

    def mean(self) -> np.ndarray:
        """Weighted mean (circular for heading and heading clones)."""
        m = self.w @ self.X
        for i in self.angles:
            m[i] = math.atan2(self.w @ np.sin(self.X[:, i]), self.w @ np.cos(self.X[:, i]))
        return m

    def cov(self) -> np.ndarray:
        """Weighted covariance about :meth:`mean` (angle residuals wrapped)."""
        D = self.X - self.mean()
        D[:, self.angles] = wrap(D[:, self.angles])
        C = (D * self.w[:, None]).T @ D
        return 0.5 * (C + C.T)

    def extra(self) -> dict:
        return {"particles": self.N, "resamples": int(self.resamples)}


def make_backend(model, models, x0, P0, walk, options) -> ParticleBackend:
    """Backend factory for :func:`odofuse.estimators.localizer.build`."""
    return ParticleBackend(model, models, x0, P0, walk, options)


def run(log, config):
    """Particle filter over a whole log: a thin wrapper feeding the log to a Localizer."""
    return run_with(log, config, "particle", make_backend)
