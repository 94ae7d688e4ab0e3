"""Odometry self-calibration in the filters: augmented states for systematic odometry errors.

Owns the filters' odometry-calibration states (:class:`FilterOdometryCalibration`): which
parameters a drive calibrates, their prior and random walk, the calibrated input
``u' = f(u, p, dt)`` and its analytic Jacobian ``du'/dp``. The parametrisation is the graph's
(:mod:`odofuse.estimators.graph.calibration`, whose table and option validation it reuses),
but evaluated exactly at the current estimate instead of to first order at the nominal values:

* ``increments``: ``p = (ds_scale a, dtheta_scale b, dtheta_bias c)``,
  ``u' = (a ds, b dtheta + c dt)`` (``c`` in rad/s); ``du'/dp = [[ds, 0, 0], [0, dtheta, dt]]``.
* ``differential`` / ``skid_steer`` (inputs ``(left, right)`` wheel angles):
  ``p = (E_d = r_R/r_L, E_b)``; ``R = phi_R 2 E_d/(1 + E_d)``, ``L = phi_L 2/(1 + E_d)`` keep the
  mean radius, ``m = (R + L)/2``, ``h = (R - L)/(2 E_b)``, ``u' = (m - h, m + h)``.

The calibration states are laid out by :func:`odofuse.estimators.localizer.state_layout` like a
measurement model's (``calib_states``, ``calib_prior``, ``calib_walk``); the backends read
``p`` from the state, predict with ``u'`` and add ``F_c = F_u du'/dp`` to the transition.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from odofuse.errors import ConfigError

#: Default random walk of each parameter, per sqrt(s): scales drift with tyre pressure, load and
#: ground (1e-4 per sqrt(s): 0.3 % per 15 min); a heading bias with temperature (1e-5 rad/s per
#: sqrt(s): 3e-4 rad/s per 15 min). Physical orders of magnitude, not fitted.
DEFAULT_WALK = {
    "ds_scale": 1e-4,
    "dtheta_scale": 1e-4,
    "dtheta_bias": 1e-5,
    "wheel_radius_ratio": 1e-4,
    "track_width_scale": 1e-4,
}


@dataclass(frozen=True)
class FilterOdometryCalibration:
    """Odometry-calibration states of one filter run.

    Parameters
    ----------
    drive : str
        ``increments``, ``differential`` or ``skid_steer``.
    names : tuple of str
        State names (also the keys of ``extra["calibration"]``).
    nominal, sigma, walk : tuple of float
        Prior mean, prior sigma and random-walk sigma per sqrt(s) of each state.
    """

    drive: str
    names: tuple[str, ...]
    nominal: tuple[float, ...]
    sigma: tuple[float, ...]
    walk: tuple[float, ...]
    index: tuple[int, ...] = field(default=())

    # -- the localizer's augmented-state protocol ------------------------------------------
    @property
    def calib_states(self) -> tuple[str, ...]:
        return self.names

    def calib_prior(self) -> dict[str, tuple[float, float]]:
        return {s: (m, sd) for s, m, sd in zip(self.names, self.nominal, self.sigma, strict=True)}

    def calib_walk(self) -> dict[str, float]:
        return dict(zip(self.names, self.walk, strict=True))

    def bind(self, index: dict[str, int]) -> FilterOdometryCalibration:
        from dataclasses import replace

        return replace(self, index=tuple(index[s] for s in self.names))

    # -- the transformation ----------------------------------------------------------------
    def apply(self, u, p, dt: float) -> np.ndarray:
        """Calibrated inputs ``u'`` ``(..., n)`` of inputs ``u`` and parameters ``p`` ``(..., m)``.

        ``dt`` is the step duration (s).
        """
        u, p = np.asarray(u, dtype=float), np.asarray(p, dtype=float)
        if self.drive == "increments":
            return np.stack([p[..., 0] * u[..., 0], p[..., 1] * u[..., 1] + p[..., 2] * dt], -1)
        E, Eb = p[..., 0], p[..., 1]
        R, L = u[..., 1] * 2.0 * E / (1.0 + E), u[..., 0] * 2.0 / (1.0 + E)
        m, h = 0.5 * (R + L), 0.5 * (R - L) / Eb
        return np.stack([m - h, m + h], -1)

    def jacobian(self, u, p, dt: float) -> np.ndarray:
        """``du'/dp`` ``(n, m)`` at one input ``u`` ``(n,)`` and parameters ``p`` ``(m,)``."""
        u, p = np.asarray(u, dtype=float), np.asarray(p, dtype=float)
        if self.drive == "increments":
            return np.array([[u[0], 0.0, 0.0], [0.0, u[1], dt]])
        E, Eb = p
        g = 2.0 / (1.0 + E) ** 2
        dR, dL = u[1] * g, -u[0] * g
        R, L = u[1] * 2.0 * E / (1.0 + E), u[0] * 2.0 / (1.0 + E)
        dm, dh = 0.5 * (dR + dL), 0.5 * (dR - dL) / Eb
        dh_b = -0.5 * (R - L) / Eb**2
        return np.array([[dm - dh, -dh_b], [dm + dh, dh_b]])


def filter_odometry_calibration(model, options, key: str, source: str):
    """The run's :class:`FilterOdometryCalibration`, or None when it is off.

    ``options`` are the filter's typed options (``odometry_calibration``,
    ``odometry_calibration_sigma``, ``odometry_calibration_walk``), or dead reckoning's (no
    walk: the default walk is set and not used).
    """
    if not getattr(options, "odometry_calibration", False):
        return None
    from odofuse.estimators.graph.calibration import odometry_calibration_for

    sig = options.odometry_calibration_sigma
    base = odometry_calibration_for(
        model, True if sig is None else list(sig), f"{key}.odometry_calibration_sigma", source
    )
    if base is None:
        return None
    if base.drive != "increments" and tuple(model.drive.input_names) != ("left", "right"):
        # the transformation reads inputs 0 and 1 as the left and right wheel
        raise ConfigError(
            "odometry calibration needs one wheel per side (inputs left, right), not "
            f"{', '.join(model.drive.input_names)}",
            file=source,
            key=f"{key}.odometry_calibration",
        )
    # Dead reckoning declares no walk: it propagates the prior alone (dead_reckoning.py).
    walk = getattr(options, "odometry_calibration_walk", None)
    if walk is None:
        walk = tuple(DEFAULT_WALK[s] for s in base.names)
    elif len(walk) != len(base.names):
        raise ConfigError(
            f"expected {len(base.names)} random-walk sigmas for {', '.join(base.names)}",
            file=source,
            key=f"{key}.odometry_calibration_walk",
        )
    return FilterOdometryCalibration(
        base.drive, base.names, base.nominal, base.sigma, tuple(map(float, walk))
    )
