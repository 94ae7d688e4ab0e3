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
"""

from __future__ import annotations

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
    Wm, Wc, c = merwe_weights(len(args["x"]), opts.alpha, opts.beta, opts.kappa)
    angles = np.asarray(angle_states(loc.models), dtype=np.int64)
    uk = (Wm, Wc, float(c), angles, SINGULAR_PIVOT, kern.ukf_work(len(Wm) // 2, args["U"].shape[1]))
    kern.filter_offline(*args.values(), uk)
    return compiled_ekf.finish(loc, log, streams, args)
