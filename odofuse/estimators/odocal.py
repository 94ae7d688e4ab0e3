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
from functools import cached_property

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
    @cached_property
    def _C(self) -> np.ndarray:
        """The track matrix ``C`` as floats, built once (a frozen dataclass keeps ``__dict__``)."""
        return np.array(self.track, dtype=float)

    @cached_property
    def _sides(self) -> tuple[int, ...]:
        """Each input's side, 0 (left) or 1 (right)."""
        return (0,) * self.wheels_per_side + (1,) * self.wheels_per_side

    def apply(self, u, p, dt: float) -> np.ndarray:
        """Calibrated inputs ``u'`` ``(..., n)`` of inputs ``u`` and parameters ``p`` ``(..., m)``.

        ``dt`` is the step duration (s). One input with one parameter vector, the filters' call
        every step (the EKF's transition, the UKF's sigma points), takes :meth:`_apply_one`: the
        array code's dozen small numpy operations made it one of their costliest calls.
        """
        u, p = np.asarray(u, dtype=float), np.asarray(p, dtype=float)
        if u.ndim == 1 and p.ndim == 1:
            return self._apply_one(u.tolist(), p.tolist(), dt)
        if self.drive == "increments":
            return np.stack([p[..., 0] * u[..., 0], p[..., 1] * u[..., 1] + p[..., 2] * dt], -1)
        # imported here: the graph package is loaded only by runs that calibrate
        from odofuse.estimators.graph.calibration import side_means

        n, C = self.wheels_per_side, self._C
        E, Eb = p[..., 0:1], p[..., 1:2]
        us = _split_radii(u, E, n)
        shift = (1.0 - 1.0 / Eb) * (side_means(us, n) @ C.T)
        out = us + np.repeat(shift, n, axis=-1)
        return out * p[..., 2:3] if len(self.names) > 2 else out

    def _apply_one(self, u: list, p: list, dt: float) -> np.ndarray:
        """:meth:`apply` of one input in plain floats, equal to the array code bit for bit: the
        same operations in the same order, the products with ``C`` left to numpy (its BLAS may
        fuse multiply and add). tests/test_filter_odometry_calibration.py checks it."""
        if self.drive == "increments":
            return np.array([p[0] * u[0], p[1] * u[1] + p[2] * dt])
        n, sides = self.wheels_per_side, self._sides
        us = _split_radii_one(u, p[0], sides)
        shift = ((1.0 - 1.0 / p[1]) * (_side_means_one(us, n) @ self._C.T)).tolist()
        out = [x + shift[j] for x, j in zip(us, sides, strict=True)]
        return np.array([x * p[2] for x in out] if len(self.names) > 2 else out)

    def jacobian(self, u, p, dt: float) -> np.ndarray:
        """``du'/dp`` ``(n, m)`` at one input ``u`` ``(n,)`` and parameters ``p`` ``(m,)``.

        A two-sided drive's is :meth:`_jacobian_one`, in plain floats: the EKF calls it every
        step, and as array code it cost five times as much.
        """
        u, p = np.asarray(u, dtype=float), np.asarray(p, dtype=float)
        if self.drive == "increments":
            return np.array([[u[0], 0.0, 0.0], [0.0, u[1], dt]])
        return self._jacobian_one(u.tolist(), p.tolist())

    def _jacobian_one(self, u: list, p: list) -> np.ndarray:
        """:meth:`jacobian` of a two-sided drive, like :meth:`_apply_one` bit for bit the array
        code's floats."""
        n, sides, C = self.wheels_per_side, self._sides, self._C
        E, Eb = p[0], p[1]
        us = _split_radii_one(u, E, sides)
        d, sign = (1.0 + E) ** 2, (-2.0, 2.0)
        dus = [x * sign[j] / d for x, j in zip(u, sides, strict=True)]  # d u_s / dE
        k = 1.0 - 1.0 / Eb
        dshift = (k * (C @ _side_means_one(dus, n))).tolist()
        Cs = (C @ _side_means_one(us, n)).tolist()
        dEb = [c / Eb**2 for c in Cs]
        if len(self.names) == 2:
            return np.array([(a + dshift[j], dEb[j]) for a, j in zip(dus, sides, strict=True)])
        Es, shift = p[2], [k * c for c in Cs]
        rows = zip(dus, us, sides, strict=True)
        return np.array([(Es * (a + dshift[j]), Es * dEb[j], b + shift[j]) for a, b, j in rows])


def _split_radii(u, E, n: int) -> np.ndarray:
    """Wheel angles ``u`` ``(..., 2n)`` with the radii split by ``E = E_d`` (mean kept): every
    right wheel's angle times ``2 E / (1 + E)``, every left wheel's times ``2 / (1 + E)``."""
    right = np.arange(2 * n) >= n
    return u * np.where(right, 2.0 * E / (1.0 + E), 2.0 / (1.0 + E))


def _split_radii_one(u: list, E: float, sides: tuple[int, ...]) -> list:
    """:func:`_split_radii` of one input in plain floats (``sides``: each input's side)."""
    w = (2.0 / (1.0 + E), 2.0 * E / (1.0 + E))
    return [x * w[j] for x, j in zip(u, sides, strict=True)]


def _side_means_one(us: list, n: int) -> np.ndarray:
    """:func:`odofuse.estimators.graph.calibration.side_means` of one input: numpy adds fewer
    than 8 terms one by one, which plain floats repeat exactly (from 8, pairwise: numpy's)."""
    if n >= 8:
        from odofuse.estimators.graph.calibration import side_means

        return side_means(us, n)
    L = R = 0.0  # as numpy's reduction: from 0.0, one term at a time (so -0.0 becomes 0.0)
    for a, b in zip(us[:n], us[n:], strict=True):
        L += a
        R += b
    return np.array((L / n, R / n))


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
