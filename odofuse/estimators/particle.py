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

Against collapse (issue 10). With only wheels and a precise gyro, nothing measures the
absolute pose, so its covariance must grow; a cloud that is reweighted and resampled at every
step by weights unrelated to the pose loses spread at every resampling instead (a random
thinning: the weighted covariance is low by ``1 - sum w^2`` and the copies add genetic drift),
which drove 20 particles from 1e-4 to 1e-14 over 10^6 gyro steps. Hence:

* **Relative measurements without degeneracy** (the gyro rate, a measurement of the heading
  change since a cloned heading): each particle's heading noise since the clone is known (it
  was drawn by :meth:`ParticleBackend.predict`), so the update uses the optimal proposal
  (Doucet, Godsill & Andrieu 2000) of this linear-Gaussian part: the particle's heading is
  redrawn from its posterior given the reading (a per-particle Kalman move with the
  *known* prior variance, not the cloud's sample covariance) and the weight is the
  predictive likelihood, whose variance includes the wheels' heading noise. The weights then
  carry what the gyro says about the bias and calibration, not a sharp selection of heading
  increments, so the effective sample size stays high and resampling is rare.
* **Unbiased kernel moments**: resampling is low-variance (systematic) and only below
  ``resample_threshold * N`` effective particles; its kernels (Liu-West for the augmented
  states, regularised for the pose: bandwidth ``h`` = ``bandwidth_scale`` times Silverman's
  ``(4 / (N (d + 2)))^(1 / (d + 4))``, ``d = 3``, Musso, Oudjane & Le Gland) use the
  reliability-weights covariance :func:`weighted_cov`, unbiased for a state the weights say
  nothing about. Heading clones move with the heading so ``theta - theta_ref`` is untouched.
* **Covariance**: :meth:`ParticleBackend.cov` is the same estimator, symmetric positive
  semi-definite by construction; a cloud that has collapsed anyway is reported by the
  Localizer's ``collapse`` check (:func:`odofuse.status.pose_checks.collapse_findings`).
* **Recovery**: :meth:`ParticleBackend.inflate` spreads the pose about its mean.

Compiled core (``options.particle.compiled``, :mod:`odofuse.estimators.compiled.particle`):
the propagation, the weighting and the cloud's moments run in numba kernels on the random
numbers this backend's generator draws, in the same order and shapes, so both paths give the
same run; what the kernels do not cover runs the numpy code below (``docs/filters.md``).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from odofuse.declarations import ParticleOptions
from odofuse.estimators.assembly import run_with
from odofuse.estimators.compiled import particle as compiled_particle
from odofuse.estimators.ekf import increment_function
from odofuse.measurements import gate_threshold
from odofuse.motion import body_increment
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


def weighted_cov(D: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Unbiased (reliability-weights) covariance of centred rows ``D`` with weights ``w``.

    ``C = sum_i w_i D_i D_i^T / (1 - sum_i w_i^2)``: for rows independent of their weights
    (a state the measurements say nothing about) ``E[C]`` is the rows' covariance, while the
    plain weighted sum is low by the factor ``1 - sum w^2`` (``(N - 1) / N`` for equal
    weights), a loss that repeated resampling would compound. Built from the eigenvalues of
    the Gram matrix of ``sqrt(w_i) D_i`` clipped at 0 (a rounding guard only), so ``C`` is
    symmetric positive semi-definite. A cloud with a single effective particle (``sum w^2 =
    1``) has no spread: zeros.

    Parameters
    ----------
    D : ndarray (N, n)
        Rows minus their weighted mean (angles wrapped).
    w : ndarray (N,)
        Normalised weights.

    Returns
    -------
    ndarray (n, n)
    """
    A = D * np.sqrt(w)[:, None]
    return _scaled_psd(A.T @ A, 1.0 - float(w @ w))


def _scaled_psd(G: np.ndarray, denom: float) -> np.ndarray:
    """``G / denom`` of a Gram matrix ``G``, eigenvalues clipped at 0 (:func:`weighted_cov`)."""
    if not denom > 1e-12:
        return np.zeros_like(G)
    vals, vecs = np.linalg.eigh(0.5 * (G + G.T))
    return (vecs * (np.clip(vals, 0.0, None) / denom)) @ vecs.T


def _inv(S: np.ndarray) -> np.ndarray:
    """``np.linalg.inv`` of a small SPD matrix; a 1 x 1 one by division (same number, a
    fifth of the cost: gyro, compass and range updates)."""
    return 1.0 / S if S.shape == (1, 1) else np.linalg.inv(S)


def psd_root(C: np.ndarray) -> np.ndarray:
    """A square root ``L`` (``L L^T = C``) of a symmetric PSD ``C``, eigenvalues clipped at 0."""
    vals, vecs = np.linalg.eigh(0.5 * (C + C.T))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


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
        width ``h``), ``regularise``, ``bandwidth_scale``, ``compiled``; a mapping is validated
        into :class:`~odofuse.declarations.ParticleOptions`.
    events : int, optional
        Rows of the log an offline run feeds (``compiled: auto`` compiles long runs only,
        :data:`odofuse.estimators.compiled.particle.AUTO_MIN_WORK`); None for a live one.
    """

    #: Odometry-calibration states (:mod:`odofuse.estimators.odocal`), set by ``assemble``.
    odo_cal = None

    def __init__(self, model, models, x0, P0, walk, options=None, events=None) -> None:
        options = coerce(ParticleOptions, options, "options.particle")
        self._kern = compiled_particle.kernels_for(options, events)
        self._terms = None  # the compiled predict's motion terms, at the first step (odo_cal)
        # robust odometry's kernel (slip_step): the motion model's linear terms, if it has them
        self._slip_terms = None if self._kern is None else compiled_particle.slip_terms(model)
        self.model = model
        self.increment = increment_function(model)  # MotionModel.increment, faster
        self.N = options.particles
        self.rng = np.random.default_rng(options.seed)
        self.resample_threshold = options.resample_threshold
        self.roughening = options.roughening
        self.options = options
        d = 3
        silverman = (4.0 / (self.N * (d + 2))) ** (1.0 / (d + 4))
        self.bandwidth = min(float(options.bandwidth_scale) * silverman, 0.99)
        if not options.regularise:
            self.bandwidth = 0.0
        x0 = np.asarray(x0, dtype=float)
        self.n = x0.size
        self.walk = np.asarray(walk, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        # Draw from N(x0, P0); P0 may be singular (clone states): use an eigen square root.
        self.X = x0 + self.rng.standard_normal((self.N, self.n)) @ psd_root(P0).T
        self.X[:, 2] = wrap(self.X[:, 2])
        self.w = np.full(self.N, 1.0 / self.N)
        self.angles = [2]
        for m in models.values():
            idx = getattr(m, "calib_index", {})
            for s in m.clones() if hasattr(m, "clones") else {}:
                if s in idx:
                    self.angles.append(idx[s])
                    self.X[:, idx[s]] = self.X[:, 2]
        self._angle_idx = np.asarray(self.angles, dtype=np.int64)
        self._is_angle = np.isin(np.arange(self.n), self.angles)
        clone_cols = set(self.angles[1:])
        # Heading clone column -> [e (N,), var_e]: the heading noise each particle was given
        # since the clone was taken, and its variance (the relative update's prior).
        self._heading_noise = {c: [np.zeros(self.N), 0.0] for c in clone_cols}
        self._kernel_cols = [i for i in range(3, self.n) if i not in clone_cols]
        self._gates = {
            id(m): gate_threshold(getattr(m, "gate", None), m.dim) for m in models.values()
        }
        self.resamples = 0
        self.moves = 0  # relative (gyro) updates assimilated by moving the heading

    # -- motion -----------------------------------------------------------------------------
    def predict(
        self,
        u,
        dt: float,
        dtheta: float | None = None,
        var_dtheta: float = 0.0,
        noise_scale: float = 1.0,
    ) -> None:
        """Sample every particle's input from the error model and move it.

        ``noise_scale`` multiplies the input variances (robust odometry during wheel slip).
        """
        u = np.asarray(u, dtype=float)
        if self._kern is not None:
            if self._terms is None:
                self._terms = compiled_particle.motion_terms(self.model, self.odo_cal) or ()
            if self._terms:
                compiled_particle.predict(
                    self, self._kern, self._terms, u, dt, dtheta, var_dtheta, noise_scale
                )
                return
        drive = self.model.drive
        var = self.model.errors.variances(drive, u, dt) * noise_scale
        U = u + self.rng.standard_normal((self.N, u.size)) * np.sqrt(var)
        U0 = u
        cal = self.odo_cal
        if cal is not None:  # each particle's own odometry calibration
            p = self.X[:, list(cal.index)]
            U, U0 = cal.apply(U, p, dt), cal.apply(np.broadcast_to(u, U.shape), p, dt)
        twist = drive.twist(U)
        delta, _ = body_increment(twist, self.model.integrator, jacobian=False)
        if dtheta is not None:
            delta = delta.copy()
            noise = self.rng.standard_normal(self.N) * math.sqrt(var_dtheta)
            delta[:, 2] = dtheta + noise
            e, var_e = noise, float(var_dtheta)
        elif self._heading_noise:
            # The heading change is the twist's rotation for every integrator.
            e = twist[:, 0] - drive.twist(U0)[..., 0]
            var_e = float(np.square(drive.J_twist_u(u)[0]) @ var)
        for acc in self._heading_noise.values():
            acc[0] += e
            acc[1] += var_e
        X = self.X
        c, s = np.cos(X[:, 2]), np.sin(X[:, 2])
        X[:, 0] += c * delta[:, 0] - s * delta[:, 1]
        X[:, 1] += s * delta[:, 0] + c * delta[:, 1]
        X[:, 2] = wrap(X[:, 2] + delta[:, 2])
        if dt > 0 and self.n > 3:
            sd = np.sqrt(self.walk[3:] * dt)
            if np.any(sd > 0):
                X[:, 3:] += self.rng.standard_normal((self.N, self.n - 3)) * sd

    def slip_step(self, u, span, g, run, slip, bias_idx, learn):
        """``slip.step_slip_scale``'s factor and run of one step in the filters' kernel
        (:func:`~odofuse.estimators.compiled.kernels.step_slip`) on the cloud's mean and
        covariance; None on the numpy path or a drive the kernels do not cover."""
        if self._slip_terms is None:
            return None
        return compiled_particle.slip_step(self, u, span, g, run, slip, bias_idx, learn)

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
        # mean innovation (angles: residuals are already small and unwrapped) and spread
        if self._kern is not None:
            y, S = np.empty(model.dim), np.empty((model.dim, model.dim))
            self._kern.pf_moments(np.ascontiguousarray(E), w, y, S)
            S = S + R
        else:
            y = w @ E
            D = E - y
            S = (D * w[:, None]).T @ D + R
        Si = _inv(S)
        nis = float(y @ Si @ y)
        self.last_innovation = (y, S, R)
        gate = self._gates.get(id(model))
        if gate is None:
            gate = self._gates[id(model)] = gate_threshold(getattr(model, "gate", None), model.dim)
        if not nis <= gate:
            return False, nis
        rel = self._relative_column(model)
        if rel is not None:
            C, Ci = self._relative_update(model, row, E, R, rel)
        else:
            C, Ci = E, _inv(R)
        if self._kern is not None:
            self.w = np.empty(self.N)
            ess = self._kern.pf_reweight(np.ascontiguousarray(C), Ci, w, self.w)
        else:
            logw = np.log(np.maximum(w, 1e-300)) - 0.5 * np.einsum("ni,ij,nj->n", C, Ci, C)
            logw -= logw.max()
            wn = np.exp(logw)
            self.w = wn / wn.sum()
            ess = 1.0 / np.sum(self.w**2)
        if ess < self.resample_threshold * self.N:
            self._resample()
        return True, nis

    def _relative_column(self, model) -> int | None:
        """The heading clone a measurement of the heading change since it refers to, or None."""
        clones = model.clones() if hasattr(model, "clones") else {}
        index = getattr(model, "calib_index", {})
        for name, src in clones.items():
            if src == 2 and index.get(name) in self._heading_noise:
                return index[name]
        return None

    def _relative_update(self, model, row, E, R, col) -> tuple[np.ndarray, np.ndarray]:
        """Optimal-proposal update by a measurement of the heading change since clone ``col``.

        Each particle's heading noise since the clone, ``e_i ~ N(0, s2)``, was drawn by
        :meth:`predict`. With ``H`` the measurement's (linear) sensitivity to the heading,
        ``c_i = z - h(x_i) + H e_i`` is the innovation of the particle without that noise, so
        the weight is the predictive likelihood ``N(c_i; 0, S)``, ``S = s2 H H^T + R`` (wide:
        the wheels' heading noise is in it), and ``e_i`` is redrawn from its posterior given
        ``z`` by the perturbed-observation Kalman move ``theta_i += K (z + v_i - h(x_i))``,
        ``K = s2 H^T S^-1``, ``v_i ~ N(0, R)`` (mean ``K c_i``, variance ``(1 - K H) s2``: exact
        for a linear ``h``). The position's (second-order) correlation with ``e_i`` is not
        moved. Returns ``(C, S^-1)``: the log-likelihoods are ``-C_i^T S^-1 C_i / 2``.
        """
        e, s2 = self._heading_noise[col]
        H = np.asarray(model.H(self.mean(), row), dtype=float)[:, 2]  # (dim,)
        C = E + e[:, None] * H
        S = s2 * np.outer(H, H) + R
        Si = _inv(S)
        if s2 > 0:
            K = s2 * (Si @ H)  # (dim,)
            V = (
                self.rng.standard_normal(E.shape)
                @ (np.sqrt(R) if R.shape == (1, 1) else np.linalg.cholesky(R)).T
            )
            step = (E + V) @ K
            self.X[:, 2] = wrap(self.X[:, 2] + step)
            e += step
            self.moves += 1
        return C, Si

    def _resample(self) -> None:
        cols = self._kernel_cols
        h = self.bandwidth
        # Kernel moments: the weighted mean and the unbiased (reliability-weights) covariance,
        # so a state the weights say nothing about keeps its spread in expectation.
        m = self.mean()
        D = self.X - m
        D[:, self.angles] = wrap(D[:, self.angles])
        C = weighted_cov(D, self.w)
        idx = low_variance_resample(self.w, self.rng)
        self.X = self.X[idx]
        for acc in self._heading_noise.values():
            acc[0] = acc[0][idx]
        self.w = np.full(self.N, 1.0 / self.N)
        self.resamples += 1
        if cols and self.roughening > 0:
            # Liu & West kernel shrinkage for the (static) augmented states: the weighted
            # posterior mean m and covariance V are kept, while duplicated particles are spread
            # again, so resampling alone does not collapse a constant parameter onto one value.
            h2 = self.roughening**2
            a = math.sqrt(1.0 - h2)
            noise = (
                self.rng.standard_normal((self.N, len(cols)))
                @ psd_root(C[np.ix_(cols, cols)] * h2).T
            )
            self.X[:, cols] = a * self.X[:, cols] + (1.0 - a) * m[cols] + noise
        if h > 0:
            # Regularised resampling of the pose: the same shrinkage kernel with Silverman's
            # bandwidth; heading clones get the heading's shift so theta - clone is kept.
            a = math.sqrt(1.0 - h * h)
            D = self.X[:, :3] - m[:3]
            D[:, 2] = wrap(D[:, 2])
            noise = self.rng.standard_normal((self.N, 3)) @ psd_root(C[:3, :3] * h * h).T
            shift = (a - 1.0) * D + noise
            self.X[:, :3] += shift
            for i in self.angles:
                if i != 2:
                    self.X[:, i] += shift[:, 2]
            self.X[:, self.angles] = wrap(self.X[:, self.angles])

    # -- bookkeeping ------------------------------------------------------------------------
    def clone(self, dst: int, src: int) -> None:
        self.X[:, dst] = self.X[:, src]
        if dst in self._heading_noise:
            self._heading_noise[dst] = [np.zeros(self.N), 0.0]

    def inflate(self, factor: float, idx) -> None:
        """Spread states ``idx`` about their weighted mean by ``sqrt(factor)`` (recovery)."""
        idx = list(idx)
        m = self.mean()
        D = self.X[:, idx] - m[idx]
        ang = [k for k, i in enumerate(idx) if i in self.angles]
        D[:, ang] = wrap(D[:, ang])
        self.X[:, idx] = m[idx] + math.sqrt(factor) * D
        self.X[:, self.angles] = wrap(self.X[:, self.angles])

    def snapshot(self):
        return (
            self.X.copy(),
            self.w.copy(),
            self.rng.bit_generator.state,
            self.resamples,
            self.moves,
            {c: [e.copy(), v] for c, (e, v) in self._heading_noise.items()},
        )

    def restore(self, snap) -> None:
        X, w, state, resamples, moves, noise = snap
        self.X, self.w = X.copy(), w.copy()
        self._heading_noise = {c: [e.copy(), v] for c, (e, v) in noise.items()}
        self.rng.bit_generator.state = state
        self.resamples, self.moves = resamples, moves

    def mean(self) -> np.ndarray:
        """Weighted mean (circular for heading and heading clones)."""
        if self._kern is not None:
            m = np.empty(self.n)
            self._kern.pf_mean(self.X, self.w, self._angle_idx, m)
            return m
        m = self.w @ self.X
        for i in self.angles:
            m[i] = math.atan2(self.w @ np.sin(self.X[:, i]), self.w @ np.cos(self.X[:, i]))
        return m

    def cov(self) -> np.ndarray:
        """Unbiased weighted covariance about :meth:`mean` (angle residuals wrapped).

        See :func:`weighted_cov`: symmetric positive semi-definite by construction.
        """
        if self._kern is not None:
            P = np.empty((self.n, self.n))
            self._kern.pf_cov(self.X, self.w, self._angle_idx, self._is_angle, P)
            return P
        D = self.X - self.mean()
        D[:, self.angles] = wrap(D[:, self.angles])
        return weighted_cov(D, self.w)

    def extra(self) -> dict:
        return {
            "particles": self.N,
            "resamples": int(self.resamples),
            "relative_moves": int(self.moves),
        }


def make_backend(model, models, x0, P0, walk, options, events=None) -> ParticleBackend:
    """Backend factory for :func:`odofuse.estimators.assembly.build` (``events``: see
    :class:`ParticleBackend`)."""
    return ParticleBackend(model, models, x0, P0, walk, options, events)


def run(log, config):
    """Particle filter over a whole log: a thin wrapper feeding the log to a Localizer."""
    events = sum(len(s) for s in log.streams.values())
    return run_with(log, config, "particle", functools.partial(make_backend, events=events))
