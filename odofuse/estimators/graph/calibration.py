"""Odometry calibration of the graph: :class:`OdometryCalibration` and its per-drive table.

Owns which systematic odometry parameters each drive can calibrate (names, nominal values,
default prior sigmas), their input Jacobian used by
:func:`odofuse.estimators.graph.keyframes.preintegrate`, and the validation of
``options.<estimator>.odometry_calibration`` (:func:`odometry_calibration_for`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odofuse.errors import ConfigError


@dataclass(frozen=True)
class OdometryCalibration:
    """Systematic odometry parameters as an input transformation ``u' = f(u, p)``.

    * ``increments`` (Plaza-style ``ds, dtheta`` logs): ``p = (ds_scale, dtheta_scale,
      dtheta_bias)``, ``u' = (a ds, b dtheta + c dt)`` (``c`` in rad/s), nominal ``(1, 1, 0)``.
    * ``differential`` / ``skid_steer`` (Borenstein's systematic errors,
      ``002_88fc37db58155723.txt``): ``p = (wheel_radius_ratio E_d = r_R / r_L,
      track_width_scale E_b)`` with the mean radius kept: ``phi_R' = phi_R 2 E_d / (1 + E_d)``,
      ``phi_L' = phi_L 2 / (1 + E_d)``, then the half difference ``h = (phi_R' - phi_L') / 2``
      divided by ``E_b``; nominal ``(1, 1)``.

    The graph uses the first-order Jacobian ``D = du'/dp`` at the nominal values.
    """

    names: tuple[str, ...]
    nominal: tuple[float, ...]
    sigma: tuple[float, ...]
    drive: str

    def input_jacobian(self, pieces, durations) -> np.ndarray:
        """``D = d u' / d p`` at the nominal parameters, shape ``(P, n, m)``."""
        pieces = np.asarray(pieces, dtype=float)
        D = np.zeros((pieces.shape[0], pieces.shape[1], len(self.names)))
        if self.drive == "increments":
            D[:, 0, 0] = pieces[:, 0]
            D[:, 1, 1] = pieces[:, 1]
            D[:, 1, 2] = np.asarray(durations, dtype=float)
        else:  # (left, right) wheel angles
            left, right = pieces[:, 0], pieces[:, 1]
            half = 0.5 * (right - left)
            D[:, 0, 0], D[:, 1, 0] = -0.5 * left, 0.5 * right
            D[:, 0, 1], D[:, 1, 1] = half, -half
        return D


_ODO_CAL = {
    "increments": (
        ("ds_scale", "dtheta_scale", "dtheta_bias"),
        (1.0, 1.0, 0.0),
        (0.05, 0.05, 0.01),
    ),
    "differential": (("wheel_radius_ratio", "track_width_scale"), (1.0, 1.0), (0.05, 0.05)),
    "skid_steer": (("wheel_radius_ratio", "track_width_scale"), (1.0, 1.0), (0.05, 0.05)),
}


def odometry_calibration_for(model, value, key, source) -> OdometryCalibration | None:
    """The :class:`OdometryCalibration` of ``options.<est>.odometry_calibration``.

    ``value`` is ``false`` (none), ``true`` (default prior sigmas) or a sequence of prior
    sigmas (numbers, already checked non-negative by the option declarations).
    """
    if value is False or value is None:
        return None
    name = model.drive.name
    if name not in _ODO_CAL:
        raise ConfigError(
            f"odometry calibration supports the {', '.join(_ODO_CAL)} drives, not '{name}'",
            file=source,
            key=key,
        )
    names, nominal, sigma = _ODO_CAL[name]
    if value is not True:
        if not isinstance(value, list | tuple) or len(value) != len(names):
            raise ConfigError(
                f"expected true or {len(names)} prior sigmas for {', '.join(names)}",
                file=source,
                key=key,
            )
        sigma = tuple(float(v) for v in value)
        if min(sigma) <= 0:
            raise ConfigError("prior sigmas must be positive", file=source, key=key)
    return OdometryCalibration(names, nominal, tuple(sigma), name)
