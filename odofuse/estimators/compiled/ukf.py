"""Compiled offline UKF: a whole log's event array through :func:`~.kernels.filter_offline`.

The run is prepared as the compiled EKF's (:func:`.ekf.prepare`: the same assembly, coverage,
event arrays and hand-over to the Localizer, :func:`.ekf.finish`) and filtered by the
kernels' form of :class:`~odofuse.estimators.ukf.UkfBackend`: filterpy's Van der Merwe
sigma points and weights (``alpha``, ``beta``, ``kappa`` of ``options.ukf``), the square root
of ``ukf._psd_sqrt``, the mean circular in theta and the heading clones, the sigma points
regenerated from the current ``x``, ``P`` before each update, the chi-square gate, the
odometry-calibration states moving each sigma point by its own calibrated input, and the
measurement functions of the compiled EKF (range to a beacon, GPS, compass, gyro rate).

Covered: what :func:`.ekf.unsupported` covers (else None and the caller runs the Python
path), with the same fallback when a recovery would have been triggered.

The streaming path: :func:`live` gives a live UKF Localizer a backend on the same kernels
(:func:`kernel_backend_class`, as the EKF's), so online equals ``odofuse run`` bit for bit on
the runs :func:`run` covers.
"""

from __future__ import annotations

import functools

import numpy as np

from odofuse.estimators.common import SINGULAR_PIVOT, angle_states
from odofuse.estimators.compiled import ekf as compiled_ekf


def merwe_weights(n: int, alpha: float, beta: float, kappa: float):
    """``(Wm, Wc, lambda + n)`` of filterpy's ``MerweScaledSigmaPoints`` (its formulas)."""
    lambda_ = alpha**2 * (n + kappa) - n
    c = 0.5 / (n + lambda_)
    Wm, Wc = np.full(2 * n + 1, c), np.full(2 * n + 1, c)
    Wc[0] = lambda_ / (n + lambda_) + (1 - alpha**2 + beta)
    Wm[0] = lambda_ / (n + lambda_)
    return Wm, Wc, lambda_ + n


def run(log, config):
    """The compiled offline UKF, or None when the run is not covered (see module doc)."""
    prep = compiled_ekf.prepare(log, config, "ukf")
    if prep is None:
        return None
    kern, loc, streams, args = prep
    opts = config.estimator_options("ukf")
    weights = _weights(len(args["x"]), opts, loc.models)
    uk = (*weights, kern.ukf_work(len(args["x"]), args["U"].shape[1]))
    kern.filter_offline(*args.values(), uk)
    return compiled_ekf.finish(loc, log, streams, args)


def _weights(n: int, opts, models) -> tuple:
    """The kernels' UKF arguments ``(Wm, Wc, lambda + n, angles, singular pivot)``."""
    Wm, Wc, c = merwe_weights(n, opts.alpha, opts.beta, opts.kappa)
    angles = np.asarray(angle_states(models), dtype=np.int64)
    return Wm, Wc, float(c), angles, SINGULAR_PIVOT


# --------------------------------------------------------------------- the streaming path
@functools.cache
def kernel_backend_class(base):
    """:class:`KernelUkfBackend` over ``base`` (``UkfBackend``, passed in so that this module
    imports neither it nor filterpy)."""

    class KernelUkfBackend(base):
        """:class:`~odofuse.estimators.ukf.UkfBackend` whose odometry predictions and gated
        updates run the kernels of :func:`run` (:func:`.kernels.ukf_predict_step`,
        :func:`.kernels.ukf_update_row`), in place on ``kf.x`` and ``kf.P``: a live Localizer
        on it computes what ``odofuse run`` computes, bit for bit, on every run :func:`run`
        covers. What the kernels do not cover runs filterpy: a prediction with a gyro heading
        (gyrodometry), a row without the kernel's columns."""

        compose_odom = compiled_ekf.compose_odom
        slip_step = compiled_ekf.slip_step

        def predict(self, u, dt, dtheta=None, var_dtheta=0.0, noise_scale=1.0) -> None:
            if dtheta is not None:
                super().predict(u, dt, dtheta, var_dtheta, noise_scale)
                return
            kf = self.kf
            self._kern.ukf_predict_step(
                kf.x, kf.P, u, dt, *self._motion_args, self.walk, float(noise_scale),
                *self._weights,
            )  # fmt: skip
            self._fresh = False  # filterpy's update regenerates its sigma points

        def update(self, model, row) -> tuple[bool, float]:
            args = compiled_ekf._update_args(self._kinds.get(type(model)), model, row)
            gate = self._gates.get(id(model))
            if args is None or gate is None:
                return super().update(model, row)
            self._pending = (model, row)
            kf = self.kf
            nis, ok = self._kern.ukf_update_row(kf.x, kf.P, *args, gate, *self._weights, self._out)
            return bool(ok), float(nis)

        last_innovation = compiled_ekf.kernel_innovation

    return KernelUkfBackend


def live(loc) -> None:
    """Give the UKF Localizer ``loc`` the compiled step kernels when ``odofuse run`` would use
    the compiled core (:func:`.ekf.swap_backend`, ``options.ukf.compiled``); else leave its
    filterpy backend."""
    backend = compiled_ekf.swap_backend(loc, "ukf", "UkfBackend", kernel_backend_class)
    if backend is not None:
        backend._weights = _weights(backend.n, loc.options, loc.models)
