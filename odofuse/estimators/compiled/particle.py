"""Compiled particle filter: :class:`~odofuse.estimators.particle.ParticleBackend`'s propagation,
weighting and moments through the numba kernels (:func:`~.kernels.pf_predict`,
:func:`~.kernels.pf_moments`, :func:`~.kernels.pf_reweight`, :func:`~.kernels.pf_mean`,
:func:`~.kernels.pf_gram`, :func:`~.kernels.pf_cov`).

Every random number is drawn by the backend's numpy Generator, in the order and shapes of the
numpy path, and handed to the kernels, so the compiled backend equals the numpy one for the same
seed (poses, weights, resampling, findings; to rounding, ``tests/test_compiled_particle.py``).

Covered: drives with ``twist = F u`` and the plain Siegwart error model
(:func:`.dead_reckoning.linear_terms`), every integrator, gyrodometry and slip noise scales,
the odometry calibration of ``increments`` and of one-wheel-a-side ``differential`` /
``skid_steer`` drives. Not covered (:func:`motion_terms` is None, the numpy ``predict`` runs):
steered and other non-linear drives, ``alphas`` or quadratic error terms, the calibration of
several wheels a side. The weighting and the moments are compiled for every sensor (the
innovations come from the models' own ``h_many`` / ``h``); resampling and the relative (gyro)
update's heading move stay numpy (rare, or one vector operation).
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.declarations import INTEGRATORS
from odofuse.estimators import compiled
from odofuse.estimators.compiled.dead_reckoning import linear_terms

#: ``compiled: auto`` compiles an offline run of at least this many particle-events (particles
#: times the log's rows): about what importing numba and loading the cached kernels costs
#: against the numpy path's per-step interpreter overhead (``docs/speed.md``, "Compiled
#: particle filter"). The choice rests on the run alone, never on whether an earlier run in the
#: process imported numba, so a log gives the same digits in ``odofuse run`` and in any
#: ``odofuse batch`` worker.
AUTO_MIN_WORK = 5_000_000

_NONE1 = np.empty(0)
_NONE2 = np.empty((0, 0))
_CAL = {"increments": 1, "differential": 2, "skid_steer": 2}


def kernels_for(options, events: int | None):
    """The kernels module for a particle run of ``events`` log rows, or None for the numpy path
    (``options.particle.compiled``). ``events`` None is a live Localizer, whose length is
    unknown: ``auto`` takes the numpy path there, as an offline run of a short log does, so
    streaming a log equals its offline run bit for bit below :data:`AUTO_MIN_WORK`; ``on``
    (or ``off``) makes both take one path on any log."""
    worth_it = events is not None and options.particles * events >= AUTO_MIN_WORK
    return compiled.enabled(options.compiled, "options.particle.compiled", worth_it)


def motion_terms(model, cal):
    """``(integ, M, K, floor, rate, cal code, C, cidx)`` of :func:`~.kernels.pf_predict`, or None
    when the drive, its error model or the odometry calibration ``cal`` is not covered."""
    terms = linear_terms(model)
    if terms is None:
        return None
    if cal is not None and (cal.drive not in _CAL or cal.wheels_per_side != 1):
        return None
    M, K, floor, rate = (np.ascontiguousarray(a, dtype=float) for a in terms)
    code = 0 if cal is None else _CAL[cal.drive]
    C = np.asarray(cal.track if cal is not None else np.zeros((2, 2)), dtype=float)
    cidx = np.asarray(cal.index if cal is not None else (), dtype=np.int64)
    return INTEGRATORS.index(model.integrator), M, K, floor, rate, code, C, cidx


def slip_terms(model):
    """``(M, K, floor, rate)`` of ``model`` for :func:`slip_step`, or None when its drive or
    error model is not linear in the input (:func:`.dead_reckoning.linear_terms`)."""
    terms = linear_terms(model)
    return None if terms is None else tuple(np.ascontiguousarray(a, dtype=float) for a in terms)


_NO_P = np.zeros((1, 1))


def slip_step(backend, u, span, g, run, slip, bias_idx, learn) -> tuple[float, float]:
    """``ParticleBackend.slip_step`` through :func:`~.kernels.step_slip`: the cloud's mean,
    and its covariance when the gyro bias is a state (the kernel reads ``P`` only then)."""
    M, K, floor, rate = backend._slip_terms
    b = -1 if bias_idx is None else int(bias_idx)
    P = _NO_P if b < 0 else backend.cov()
    u = np.ascontiguousarray(u, dtype=float)
    return backend._kern.step_slip(
        backend.mean(), P, u, span, g, M, K, floor, rate, slip, b, run, learn
    )  # fmt: skip


def predict(backend, kern, terms, u, dt, dtheta, var_dtheta, noise_scale) -> None:
    """``backend.predict`` (same arguments, same draws) through :func:`~.kernels.pf_predict`."""
    integ, M, K, floor, rate, cal, C, cidx = terms
    b = backend
    var = (K @ np.abs(u) + floor + rate * max(dt, 0.0)) * noise_scale
    Z = b.rng.standard_normal((b.N, u.size))
    Zth, sd_th = _NONE1, 0.0
    if dtheta is not None:
        Zth, sd_th = b.rng.standard_normal(b.N), math.sqrt(var_dtheta)
    Zw, sd_w = _NONE2, _NONE1
    if dt > 0 and b.n > 3:
        sd = np.sqrt(b.walk[3:] * dt)
        if np.any(sd > 0):
            Zw, sd_w = b.rng.standard_normal((b.N, b.n - 3)), sd
    e = np.empty(b.N) if b._heading_noise else _NONE1
    d = 0.0 if dtheta is None else float(dtheta)
    kern.pf_predict(b.X, u, var, Z, integ, M, cal, C, cidx, float(dt), Zth, sd_th, d, e, Zw, sd_w)
    if b._heading_noise:
        var_e = float(var_dtheta) if dtheta is not None else float(np.square(M[0]) @ var)
        for acc in b._heading_noise.values():
            acc[0] += e
            acc[1] += var_e
