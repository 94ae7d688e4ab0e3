"""Advice on the robot's geometry from a run's odometry calibration: never a finding.

With an absolute sensor fused, the filters and the batch smoother estimate the wheels'
systematic errors by default (``odometry_calibration: auto``; docs/filters.md): a wheel radius
or track a few percent off is then part of the model, the run stays consistent, and ``status``
has nothing to say about it. What the user can still want is the config value the log
supports. Where a calibration state's estimate is significant (its nominal value outside the
estimate's two-sided ``1 - ADVICE_ALPHA`` interval, ``|z| > 3.29``), the run's ``advice`` names
the config key and the value that would match the log. Like the second opinion's accuracy
advice it never changes ``status``; on a robot whose geometry is exactly the configured one
each state advises with probability ``ADVICE_ALPHA``.

Whether a 3 % error is seen depends on the log: on the status benchmark's 94 s logs the wheel
radius scale's sigma is 1-1.8 % (docs/trust.md, "Advice on the robot's geometry").
"""

from __future__ import annotations

import math
from statistics import NormalDist

#: Two-sided probability that a state advises on a log whose geometry is the configured one.
ADVICE_ALPHA = 1e-3


def calibration_estimates(extra: dict) -> dict[str, tuple[float, float, float]]:
    """``name -> (value, sigma, nominal)`` of the run's odometry calibration states with a
    sigma (the states and their nominal values: ``odofuse.estimators.graph.calibration``).

    The filters give ``extra["calibration"][name] = {"value", "sigma"}``; the graph back ends
    ``extra["calibration"][name]`` (the value) and ``extra["calibration_sigma"][name]``.
    """
    cal, sig = extra.get("calibration") or {}, extra.get("calibration_sigma") or {}
    if not cal:  # no calibration: the graph package is not loaded for nothing
        return {}
    from odofuse.estimators.graph.calibration import nominal_values

    out = {}
    for name, nominal in nominal_values().items():
        v = cal.get(name)
        value, sigma = (
            (v.get("value"), v.get("sigma")) if isinstance(v, dict) else (v, sig.get(name))
        )
        if value is not None and sigma is not None and math.isfinite(value) and sigma > 0:
            out[name] = (float(value), float(sigma), nominal)
    return out


def geometry_advice(robot: dict, extra: dict, alpha: float = ADVICE_ALPHA) -> list[str]:
    """One advice line per significant odometry calibration state of a run.

    ``robot`` is the config's ``robot`` mapping, ``extra`` the run's ``extra``.
    """
    z_crit = NormalDist().inv_cdf(1.0 - alpha / 2.0)
    lines = []
    for name, (value, sigma, nominal) in calibration_estimates(extra).items():
        z = (value - nominal) / sigma
        if abs(z) <= z_crit:
            continue
        fit = f"{value:.4g} +- {sigma:.2g}, {abs(z):.1f} sigma from {nominal:g}"
        lines.append(f"{_what(name, value, robot)} ({fit}; odometry calibration)")
    return lines


def _what(name: str, value: float, robot: dict) -> str:
    """The advice of state ``name`` at ``value``: the config key and the value fitting the log."""
    r = robot.get("wheel_radius")
    left, right = robot.get("wheel_radius_left", r), robot.get("wheel_radius_right", r)
    if name == "wheel_radius_scale" and left is not None and right is not None:
        if left == right:
            return f"the wheel radius fits this log at {value * left:.5g} m: `robot.wheel_radius`"
        return (
            f"the wheel radii fit this log at {value * left:.5g} m (left) and "
            f"{value * right:.5g} m (right): `robot.wheel_radius_left`, `wheel_radius_right`"
        )
    if name == "wheel_radius_ratio" and left is not None and right is not None:
        # the ratio splits the radii with their mean kept (odofuse.estimators.odocal)
        new_left, new_right = 2.0 * left / (1.0 + value), 2.0 * value * right / (1.0 + value)
        return (
            f"the right wheels' radius fits this log at {value:.4g} of the left's: "
            f"`robot.wheel_radius_left: {new_left:.5g}`, `wheel_radius_right: {new_right:.5g}`"
        )
    if name == "track_width_scale":
        if robot.get("y_l") is not None and robot.get("y_r") is not None:  # skid steer's ICRs
            return (
                f"the treads' ICRs fit this log at y_l {value * robot['y_l']:.5g} m, y_r "
                f"{value * robot['y_r']:.5g} m: `robot.y_l`, `robot.y_r`"
            )
        if robot.get("track_width") is not None:
            return (
                f"the track fits this log at {value * robot['track_width']:.5g} m: "
                "`robot.track_width`"
            )
    if name == "dtheta_bias":
        return f"the odometry's heading change carries a bias of {value:.3g} rad/s"
    what = {"ds_scale": "distances", "dtheta_scale": "heading changes"}.get(name, name)
    return f"the odometry's {what} fit this log at {value:.4g} times their logged values"
