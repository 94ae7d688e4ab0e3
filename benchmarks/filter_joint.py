"""The joint covariance of a Kalman filter's errors over a run, as the filter's own model states it.

A filter reports one covariance per pose, ``P_k``; its errors at two times are correlated,
and how strongly follows from the same model: between two poses the error moves by the
filter's closed loop, ``e+ = F e + noise`` in a prediction (``F`` the motion Jacobian) and
``e+ = (I - K H) e - K v`` in an accepted update, so ``Cov(e_j, e_i) = Phi(j, i) P_i`` for
``j >= i``, ``Phi(j, i)`` the product of those matrices in between (Bar-Shalom, Li and
Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, sec. 5.4; the
error recursion of the Kalman filter). :func:`recording` runs a filter on its Python path with
the backend's operations observed and keeps ``Phi`` and ``P`` for every pose of the
trajectory; :func:`joint_position_covariance` assembles the joint covariance of the positions
at chosen poses, which ``bench_status.joint_bound`` turns into the exact 99.9 % point of the
run's mean NEES (as ``bench_status.model_nees_bound`` does for a graph solution).

The operations: a prediction multiplies by the motion Jacobian at the filter's mean
(:meth:`EkfBackend.transition` with odometry calibration, ``I + c e_theta^T`` without); an
accepted update by ``I - K H``, ``K`` the filter's own gain and ``H`` the measurement model's
Jacobian at the prior; a rejected one by nothing; a clone copies the source state's row; an
inflation (a recovery, ``P <- D P D``) scales the error by ``D`` (adding the difference as
independent noise instead is not a covariance: ``D P D - P`` is indefinite where ``P``
correlates the pose with the other states). The UKF takes the
same Jacobians at its own mean with its own gain: the statistical linearisation from its sigma
points (``F = P_xx'^T P^-1``) was tried first and is ill-conditioned beside a fresh heading
clone, where ``P`` is singular. Benchmark code only: nothing in odofuse calls it.
"""

from __future__ import annotations

import contextlib

import numpy as np


class _Record:
    def __init__(self) -> None:
        self.M = None  # the closed loop since the last pose (None: the identity)
        self.steps: list = []  # (Phi, P) per trajectory pose

    def apply(self, A: np.ndarray) -> None:
        self.M = A if self.M is None else A @ self.M


def _hooks(rec: _Record, backend_cls):
    """The observed ``predict``, ``update``, ``clone`` and ``inflate`` of an EKF or UKF backend
    class."""
    from odofuse.estimators.ekf import EkfBackend

    predict, update, clone = backend_cls.predict, backend_cls.update, backend_cls.clone
    inflate = backend_cls.inflate

    def h_predict(self, u, dt, dtheta=None, var_dtheta=0.0, noise_scale=1.0):
        x = self.kf.x.copy()
        if self.odo_cal is not None:
            F = EkfBackend.transition(self, x, np.asarray(u, dtype=float), dt, dtheta)[1]
        predict(self, u, dt, dtheta, var_dtheta, noise_scale)
        if self.odo_cal is None:
            xn = self.kf.x
            F = np.eye(self.n)
            F[0, 2], F[1, 2] = -(xn[1] - x[1]), xn[0] - x[0]
        rec.apply(F)

    def h_update(self, model, row):
        x0 = self.kf.x.copy()
        accepted, nis = update(self, model, row)
        if accepted:
            H = np.atleast_2d(model.H(x0, row))
            rec.apply(np.eye(self.n) - self.kf.K @ H)
        return accepted, nis

    def h_clone(self, dst, src):
        clone(self, dst, src)
        E = np.eye(self.n)
        E[dst] = 0.0
        E[dst, src] = 1.0
        rec.apply(E)

    def h_inflate(self, factor, idx):
        inflate(self, factor, idx)
        D = np.ones(self.n)
        D[list(idx)] = np.sqrt(factor)
        rec.apply(np.diag(D))

    return {"predict": h_predict, "update": h_update, "clone": h_clone, "inflate": h_inflate}


def _no_replay(self, snap):
    raise RuntimeError("filter_joint: a replay (late reading) is not recorded")


@contextlib.contextmanager
def recording(estimator: str):
    """Observe the Python-path backend of ``estimator`` (``ekf`` or ``ukf``) while the block
    runs one filter: yields the list that receives ``(Phi, P)`` for every trajectory pose
    (``Phi`` ``(n, n)`` the closed loop from the previous pose, None for the identity;
    ``P`` ``(n, n)`` the full state covariance)."""
    from odofuse.estimators import ekf, ukf
    from odofuse.estimators.history import Track

    cls = {"ekf": ekf.EkfBackend, "ukf": ukf.UkfBackend}[estimator]
    rec = _Record()
    hooks = _hooks(rec, cls)
    hooks["restore"] = _no_replay
    append = Track.append
    current: dict = {}

    def h_init(self, *a, **k):  # the backend that the track's poses come from
        init(self, *a, **k)
        if current:
            raise RuntimeError("filter_joint: a second backend in one recording")
        current["b"] = self

    def h_append(self, t, x, P):
        append(self, t, x, P)
        b = current.get("b")
        rec.steps.append((rec.M, None if b is None else b.cov().copy()))
        rec.M = None

    init = cls.__init__
    saved = {name: getattr(cls, name) for name in hooks}
    try:
        cls.__init__ = h_init
        for name, fn in hooks.items():
            setattr(cls, name, fn)
        Track.append = h_append
        yield rec.steps
    finally:
        cls.__init__ = init
        for name, fn in saved.items():
            setattr(cls, name, fn)
        Track.append = append


def run_recorded(log, cfg, estimator: str):
    """``(trajectory, steps)``: ``estimator`` (``ekf`` / ``ukf``) on its Python path over
    ``log`` with ``cfg`` (:func:`odofuse.estimators.assembly.run_with`), recorded."""
    from odofuse.estimators import ekf, ukf
    from odofuse.estimators.assembly import run_with

    make = {"ekf": ekf.make_backend, "ukf": ukf.make_backend}[estimator]
    with recording(estimator) as steps:
        result = run_with(log, cfg, estimator, make)
    return result.trajectory, steps


def joint_position_covariance(steps, idx) -> np.ndarray:
    """Joint covariance ``(2m, 2m)`` (world frame) of the position errors at the trajectory
    poses ``idx`` (increasing), from the recorded ``steps``: block ``(j, i)`` is
    ``Phi(j, i) P_i`` restricted to the position rows and columns, ``j >= i``."""
    idx = np.asarray(idx)
    m = len(idx)
    if m and steps[int(idx[0])][1] is None:
        raise ValueError("filter_joint: a pose before the backend existed")
    # closed loop between consecutive chosen poses
    T = [None] * m
    for a in range(1, m):
        G = None
        for k in range(int(idx[a - 1]) + 1, int(idx[a]) + 1):
            A = steps[k][0]
            if A is not None:
                G = A if G is None else A @ G
        T[a] = G
    S = np.zeros((m, 2, m, 2))
    for i in range(m):
        G = steps[int(idx[i])][1]
        S[i, :, i, :] = G[:2, :2]
        for j in range(i + 1, m):
            if T[j] is not None:
                G = T[j] @ G
            S[j, :, i, :] = G[:2, :2]
            S[i, :, j, :] = G[:2, :2].T
    S = S.reshape(2 * m, 2 * m)
    return 0.5 * (S + S.T)


def worst_added_noise(steps) -> float:
    """The smallest eigenvalue, over the run, of the noise each pose added under the recorded
    closed loop, ``P_k - Phi_k P_k-1 Phi_k^T`` in correlation scale (by ``sqrt(diag P_k)``):
    a Kalman filter adds ``Q`` and ``K R K^T``, so it is >= 0 up to rounding when ``Phi`` is
    the filter's own closed loop (a wrong sign or factor in ``Phi`` makes it negative)."""
    worst = np.inf
    for k in range(1, len(steps)):
        A, P = steps[k]
        prev = steps[k - 1][1]
        if prev is None:
            continue
        D = P - (prev if A is None else A @ prev @ A.T)
        d = np.sqrt(np.clip(np.diagonal(P), 1e-300, None))
        worst = min(worst, float(np.linalg.eigvalsh(D / np.outer(d, d))[0]))
    return worst
