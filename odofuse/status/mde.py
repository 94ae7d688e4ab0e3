"""Minimal detectable errors: for each sensor gate, NIS window and innovation-mean scan of a
filter, the smallest error of a reading it detects with probability ``mde_power`` at its
false-alarm probability, in the sensor's units (``metrics.json`` ``sensors.<s>.mde``), and the
``inert`` note of a gate that can never fire (issue 25, item 4; docs/trust.md).
"""

from __future__ import annotations

import functools
import math
from statistics import NormalDist

import numpy as np

from odofuse.status.findings import Finding
from odofuse.status.pose_checks import _s
from odofuse.status.streaming import mean_bound, window_band


@functools.lru_cache(maxsize=64)
def _normal_quantile(p: float) -> float:
    """The standard normal ``p``-quantile (a few options' values: cached for the live health)."""
    return NormalDist().inv_cdf(p)


def _largest_eigenvalue(S: np.ndarray) -> float:
    """The largest eigenvalue of the symmetric part of ``S`` (d, d); closed form for d <= 2
    (the live health asks it of every stream each pass)."""
    if S.shape == (1, 1):
        return float(S[0, 0])
    if S.shape == (2, 2):
        (a, b), (c, d) = S.tolist()
        m, h = 0.5 * (a + d), 0.5 * (b + c)
        return m + math.hypot(0.5 * (a - d), h)
    return float(np.linalg.eigvalsh(0.5 * (S + S.T))[-1])


def gate_mde(gate: float, s_max: float, power: float) -> float:
    """Smallest error of one reading that its gate rejects with probability >= ``power``.

    ``(sqrt(gate) + z_power) * sqrt(s_max)``, ``s_max`` the largest eigenvalue of the
    innovation covariance ``S``: an error ``b`` along the worst direction has noncentrality
    ``|b|^2 / s_max``, and the NIS is at least the squared innovation along ``b`` (in ``S``'s
    metric), so the gate fires when that normal draw exceeds ``sqrt(gate)``.
    """
    if not (math.isfinite(gate) and s_max > 0.0):
        return math.inf
    return (math.sqrt(gate) + _normal_quantile(power)) * math.sqrt(s_max)


def window_mde(k: int, w: int, d: int, s_max: float, opts) -> float:
    """Smallest constant error of a stream's readings that its NIS window check detects.

    The error must hold over ``health_persist`` windows, each failing with probability
    ``mde_power^(1 / health_persist)``; a window's summed NIS is then noncentral chi-square
    (``w d`` degrees of freedom, noncentrality ``lambda = w |b|^2 / s_max`` in the worst
    direction), taken normal (mean ``w d + lambda``, variance ``2 (w d + 2 lambda)``): its
    ``1 - power`` quantile reaches the bound ``w hi`` at
    ``lambda = (s^2 - w d) / 2``, ``s = z sqrt(2) + sqrt(2 z^2 + 2 w hi - w d)``.
    """
    if not s_max > 0.0:
        return math.inf
    persist = int(opts.health_persist)
    _, hi, _ = window_band(k + 1, w, d, opts.nis_alpha, persist)
    z = _normal_quantile(float(opts.mde_power) ** (1.0 / persist))
    nu, bound = w * d, w * hi
    root = z * math.sqrt(2.0) + math.sqrt(max(2.0 * z * z + 2.0 * bound - nu, 0.0))
    lam = max(0.5 * (root * root - nu), 0.0)
    return math.sqrt(lam / w * s_max)


def mean_mde(j: int, w: int, d: int, s_max: float, opts) -> float:
    """Smallest constant error of ``w`` readings that the innovation-mean scan's ``j``-th
    evaluation detects with probability ``mde_power``: ``(sqrt(bound) + z_power) *
    sqrt(s_max / w)`` (:func:`gate_mde`'s argument for a window's whitened sum, whose mean
    along the error is ``sqrt(w) |b| / sqrt(s_max)`` in the worst direction)."""
    if not s_max > 0.0:
        return math.inf
    bound, _ = mean_bound(j, d, opts.nis_alpha)
    z = _normal_quantile(float(opts.mde_power))
    return (math.sqrt(bound) + z) * math.sqrt(s_max / w)


def heading_increment_var(loc, dt: float) -> float:
    """Variance (rad^2) of the wheels' heading change over ``dt`` s at the last odometry
    step's rate: ``dt / span`` steps of that step's input ``u``, each adding the motion
    model's ``(F_u Sigma_u F_u^T)_theta`` (0 before the first step)."""
    if loc._last_step is None:
        return 0.0
    u, span = loc._last_step
    if not (span > 0.0 and dt > 0.0):
        return 0.0
    _, P, _, _ = loc.motion_model.predict(np.zeros(3), np.zeros((3, 3)), u)
    return float(P[2, 2]) * dt / span


def mde_of(loc) -> dict:
    """Sensor -> ``{"gate", "nis_window", "innovation_mean"}``: the smallest error of a
    reading each check of the stream detects with probability ``mde_power`` (in the sensor's
    units), at the innovation covariance of the stream's last reading under the current
    state covariance (:func:`gate_mde`, :func:`window_mde`, :func:`mean_mde`); None where no
    reading was seen.

    A stream measured against a heading clone (a gyro: ``theta - theta_ref`` over the
    reading's ``dt``) finds its clone just reset, so the covariance now says nothing of the
    wheels' heading noise its next reading meets: that is added at the last odometry step's
    rate (:func:`heading_increment_var`). Without it a 0.01 rad/s gyro on wheels of ``k``
    2e-5 m reported a sixth of its innovations' sigma (docs/trust.md, "The gyro in the
    innovation-mean scan").
    """
    mon, opts = loc.monitor, loc.options
    mon.catch_up()
    x, Pfull = loc.backend.mean(), loc.backend.cov()
    out = {}
    for s, row in loc._last_row.items():
        model = loc.models[s]
        try:
            H = np.atleast_2d(np.asarray(model.H(x, row), dtype=float))
            S = H @ Pfull @ H.T + np.atleast_2d(model.R(row))
            if s in mon.rate_streams and "dt" in row:
                S = S + np.outer(H[:, 2], H[:, 2]) * heading_increment_var(loc, row["dt"])
            s_max = _largest_eigenvalue(S)
        except (KeyError, ValueError, np.linalg.LinAlgError):
            continue  # a row the model cannot read at this state: no figure
        if not math.isfinite(s_max):
            continue
        gate = gate_mde(mon.gates[s], s_max, float(opts.mde_power))
        w = max(int(opts.nis_window), 1)
        window = window_mde(mon.live[s].k, w, mon.dims[s], s_max, opts)
        out[s] = {
            "gate": gate if math.isfinite(gate) else None,
            "nis_window": window if math.isfinite(window) else None,
        }
        mean = mean_mde(mon.live[s].mk + 1, w, mon.dims[s], s_max, opts)
        if s in mon.rate_streams:  # a block sums blen readings (_rate_block)
            mean /= math.sqrt(max(mon.live[s].blen, 1))
        out[s]["innovation_mean"] = mean if math.isfinite(mean) else None
    return out


def inert_findings(loc, mde: dict) -> list:
    """A note per stream whose gate can never fire: no gate, or a smallest detectable error
    larger than the whole span its readings covered (max - min of each component)."""
    out = []
    for s, m in mde.items():
        span = loc._z_span.get(s)
        width = float(np.max(span[1] - span[0])) if span is not None else math.nan
        gate = m["gate"]
        if gate is not None and not (math.isfinite(width) and gate > width > 0.0):
            continue
        what = (
            "it has no gate"
            if gate is None
            else f"its smallest detectable error {_s(gate)} exceeds the span {_s(width)} "
            "of all its readings"
        )
        out.append(
            Finding(
                "inert",
                f"the gate can never fire: {what}; a fault of this sensor goes unseen",
                sensor=s,
                figure=gate,
                degrades=False,
            )
        )
    return out
