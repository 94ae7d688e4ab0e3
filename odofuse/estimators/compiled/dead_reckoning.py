"""Compiled dead reckoning: :func:`odofuse.motion.dead_reckon` through the numba kernels.

Every drive and integrator is covered: a drive with ``twist = F u`` (``matrix()``) and the
plain Siegwart error model runs entirely in :func:`~.kernels.dr_linear`; any other drive or
error model (quadratic terms, steering) gets its twists, ``J_twist_u`` and input variances from
the drive and error model themselves, in blocks, and :func:`~.kernels.dr_generic` integrates.
"""

from __future__ import annotations

import numpy as np

from odofuse import motion
from odofuse.declarations import INTEGRATORS
from odofuse.estimators import compiled

#: Steps per block of the generic path (bounds the temporaries to a few MB).
BLOCK = 65536
#: ``auto`` compiles dead reckoning from this many steps on: the vectorised numpy path does
#: 10^6 steps with covariance in about 0.4 s, about what importing numba and loading the
#: cached kernels costs. The choice rests on the log alone, never on whether numba is already
#: imported, so a log gives the same digits in ``odofuse run`` and in any ``odofuse batch``
#: worker (the two paths round differently in the last bits).
AUTO_MIN_STEPS = 1_000_000


def linear_terms(model):
    """:func:`odofuse.motion.linear_terms`, checked: None unless the drive is linear, the error
    model has no quadratic term and ``K |u| + floor + rate dt`` equals
    :meth:`~odofuse.motion.OdometryErrorModel.variances` on a few inputs."""
    terms = motion.linear_terms(model)
    if terms is None or model.errors.quadratic is not None:
        return None
    M, K, floor, rate = terms
    rng = np.random.default_rng(0)
    for u in rng.normal(0.0, 0.5, (3, M.shape[1])):
        ref = model.errors.variances(model.drive, u, 0.1)
        if not np.allclose(K @ np.abs(u) + floor + rate * 0.1, ref, rtol=1e-12, atol=1e-15):
            return None
    return terms


def dead_reckon(model, pose0, P0, U, with_cov: bool = True, mode: str = "auto"):
    """:func:`odofuse.motion.dead_reckon` (same arguments and result), compiled when ``mode``
    and numba allow (``auto``: from :data:`AUTO_MIN_STEPS` steps), else the vectorised numpy
    reference."""
    n = len(model.drive.input_names)
    U = np.ascontiguousarray(np.asarray(U, dtype=float).reshape(-1, n))
    k = compiled.enabled(mode, "options.dead_reckoning.compiled", U.shape[0] >= AUTO_MIN_STEPS)
    if k is None:
        return motion.dead_reckon(model, pose0, P0, U, with_cov)
    pose = np.array(pose0, dtype=float).reshape(3)
    P = np.array(P0, dtype=float).reshape(3, 3)
    N = U.shape[0]
    integ = INTEGRATORS.index(model.integrator)
    poses = np.empty((N + 1, 3))
    covs = np.empty((N + 1, 3, 3)) if with_cov else np.empty((1, 3, 3))
    terms = linear_terms(model)
    if terms is not None:
        M, K, floor, _ = terms
        k.dr_linear(pose, P, U, M, K, floor, integ, with_cov, poses, covs)
        return poses, (covs if with_cov else None)
    P = 0.5 * (P + P.T)
    poses[0] = pose
    covs[0] = P
    for m in range(0, N, BLOCK):
        Ub = U[m : m + BLOCK]
        twist = np.ascontiguousarray(model.drive.twist(Ub), dtype=float).reshape(-1, 3)
        if with_cov:
            J = np.ascontiguousarray(model.drive.J_twist_u(Ub), dtype=float).reshape(-1, 3, n)
            var = np.ascontiguousarray(model.errors.variances(model.drive, Ub), dtype=float)
            var = var.reshape(-1, n)
            cb = covs[m + 1 : m + 1 + len(Ub)]
        else:
            J, var, cb = np.empty((0, 3, n)), np.zeros((1, n)), covs
        k.dr_generic(pose, P, twist, J, var, integ, with_cov, poses[m + 1 : m + 1 + len(Ub)], cb)
    return poses, (covs if with_cov else None)
