"""Odometry self-calibration in the filters: augmented states for systematic odometry errors.

Owns the filters' odometry-calibration states (:class:`FilterOdometryCalibration`): which
parameters a drive calibrates, their prior and random walk, the calibrated input
``u' = f(u, p, dt)`` and its analytic Jacobian ``du'/dp``. The parametrisation is the graph's
(:mod:`odofuse.estimators.graph.calibration`, whose table and option validation it reuses),
but evaluated exactly at the current estimate instead of to first order at the nominal values:

* ``increments``: ``p = (ds_scale a, dtheta_scale b, dtheta_bias c)``,
  ``u' = (a ds, b dtheta + c dt)`` (``c`` in rad/s); ``du'/dp = [[ds, 0, 0], [0, dtheta, dt]]``.
* ``differential`` / ``skid_steer`` (inputs ``left1 .. leftn, right1 .. rightn``):
  ``p = (E_d = r_R/r_L, E_b)``; every right wheel's angle times ``2 E_d/(1 + E_d)``, every left
  wheel's times ``2/(1 + E_d)`` (the mean radius kept), giving ``u_s`` with side means
  ``s = (L, R)``; then every wheel of a side moves by that side's ``(1 - 1/E_b) C s``
  (``C``: :func:`odofuse.estimators.graph.calibration.track_matrix`), which makes the drive
  exactly the one with its track (skid steer: ICR coordinates ``y_l, y_r``) scaled by ``E_b``.
  With one wheel a side, equal radii and ``y_l = -y_r``: ``m = (R + L)/2``,
  ``h = (R - L)/(2 E_b)``, ``u' = (m - h, m + h)``. With a third state ``E_s``
  (``wheel_radius_scale``, the default) every angle of that ``u'`` is times ``E_s``.

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
    "wheel_radius_scale": 1e-4,
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
    #: wheels on each side and the track matrix ``C`` (:class:`OdometryCalibration`)
    wheels_per_side: int = 1
    track: tuple[tuple[float, float], tuple[float, float]] = ((-0.5, 0.5), (0.5, -0.5))

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
        # imported here: the graph package is loaded only by runs that calibrate
        from odofuse.estimators.graph.calibration import side_means

        n, C = self.wheels_per_side, np.asarray(self.track)
        E, Eb = p[..., 0:1], p[..., 1:2]
        us = _split_radii(u, E, n)
        shift = (1.0 - 1.0 / Eb) * (side_means(us, n) @ C.T)
        out = us + np.repeat(shift, n, axis=-1)
        return out * p[..., 2:3] if len(self.names) > 2 else out

    def jacobian(self, u, p, dt: float) -> np.ndarray:
        """``du'/dp`` ``(n, m)`` at one input ``u`` ``(n,)`` and parameters ``p`` ``(m,)``."""
        u, p = np.asarray(u, dtype=float), np.asarray(p, dtype=float)
        if self.drive == "increments":
            return np.array([[u[0], 0.0, 0.0], [0.0, u[1], dt]])
        from odofuse.estimators.graph.calibration import side_means

        n, C = self.wheels_per_side, np.asarray(self.track)
        E, Eb = p[0], p[1]
        us = _split_radii(u, E, n)
        dus = u * np.where(np.arange(2 * n) >= n, 2.0, -2.0) / (1.0 + E) ** 2  # d u_s / dE
        dE = dus + np.repeat((1.0 - 1.0 / Eb) * (C @ side_means(dus, n)), n)
        dEb = np.repeat(C @ side_means(us, n) / Eb**2, n)
        if len(self.names) == 2:
            return np.stack([dE, dEb], -1)
        Es = p[2]
        f = us + np.repeat((1.0 - 1.0 / Eb) * (C @ side_means(us, n)), n)
        return np.stack([Es * dE, Es * dEb, f], -1)


def _split_radii(u, E, n: int) -> np.ndarray:
    """Wheel angles ``u`` ``(..., 2n)`` with the radii split by ``E = E_d`` (mean kept): every
    right wheel's angle times ``2 E / (1 + E)``, every left wheel's times ``2 / (1 + E)``."""
    right = np.arange(2 * n) >= n
    return u * np.where(right, 2.0 * E / (1.0 + E), 2.0 / (1.0 + E))


def filter_odometry_calibration(model, options, key: str, source: str):
    """The run's :class:`FilterOdometryCalibration`, or None when it is off.

    ``options`` are the filter's typed options (``odometry_calibration``,
    ``odometry_calibration_sigma``, ``odometry_calibration_walk``), or dead reckoning's (no
    walk: the default walk is set and not used). Every filter, the particle filter included,
    carries a two-sided drive's ``wheel_radius_scale`` by default (docs/filters.md).
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
        base.drive,
        base.names,
        base.nominal,
        base.sigma,
        tuple(map(float, walk)),
        wheels_per_side=base.wheels_per_side,
        track=base.track,
    )
