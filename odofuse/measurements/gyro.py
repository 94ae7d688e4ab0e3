"""The yaw-rate model :class:`GyroYawRate`: the gyro against the heading change since the
previous sample (a cloned heading state), with an optional bias state."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from odofuse.measurements.base import (
    MeasurementModel,
    _pose_of,
    _scalar_of,
)
from odofuse.se2 import wrap, wrap_angle


@dataclass(frozen=True)
class GyroYawRate(MeasurementModel):
    """Gyro yaw rate as a measurement of the heading change since the previous gyro sample.

    The pose state has no yaw rate, so the filter keeps a clone ``gyro_theta_ref`` of the
    heading at the previous gyro time ``t_ref`` (stochastic cloning): ``clones()`` asks the
    filter to reset it to ``theta`` after every gyro row. With ``dt = row["dt"]`` (set by the
    filter: ``t - t_ref``)::

        h(x) = wrap(theta - theta_ref) / dt + b

    where ``b`` is the optional ``gyro_bias`` state (rad/s). The rate is thus compared with
    the mean rate over the interval (exact for a constant rate; the gyro sample is assumed
    representative of the interval, as in the gyrodometry of ``002_88fc37db58155723.txt``).
    """

    calibrate: bool = True  # a gyro's bias is estimated unless the config says otherwise
    bias_sigma: float = 0.01
    bias_walk: float = 0.0

    @property
    def calib_states(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("gyro_theta_ref", "gyro_bias") if self.calibrate else ("gyro_theta_ref",)

    def calib_prior(self):
        prior = {"gyro_theta_ref": (0.0, 0.0)}
        if self.calibrate:
            prior["gyro_bias"] = (0.0, self.bias_sigma)
        return prior

    def calib_walk(self):
        walk = {"gyro_theta_ref": 0.0}
        if self.calibrate:
            walk["gyro_bias"] = self.bias_walk
        return walk

    def clones(self):
        return {"gyro_theta_ref": 2}

    def z(self, row) -> np.ndarray:
        return np.array([float(row["wz"])])

    @staticmethod
    def _dt(row) -> float:
        dt = float(row.get("dt", 0.0))
        if not dt > 0.0:
            raise ValueError("GyroYawRate needs row['dt'] > 0 (time since the previous gyro row)")
        return dt

    def h(self, x, row) -> np.ndarray:
        dt = self._dt(row)
        ref = self._get(x, "gyro_theta_ref", float(x[2]))
        return np.array([wrap_angle(x[2] - ref) / dt + self._get(x, "gyro_bias", 0.0)])

    def h_many(self, X, row) -> np.ndarray:
        dt = self._dt(row)
        ref = self._get_many(X, "gyro_theta_ref", X[:, 2])
        return (wrap(X[:, 2] - ref) / dt + self._get_many(X, "gyro_bias", 0.0))[:, None]

    def H(self, x, row) -> np.ndarray:
        dt = self._dt(row)
        J = np.zeros((1, len(x)))
        J[0, 2] = 1.0 / dt
        c = self._col("gyro_theta_ref", len(x))
        if c is not None:
            J[0, c] = -1.0 / dt
        c = self._col("gyro_bias", len(x))
        if c is not None:
            J[0, c] = 1.0
        return J

    def factor(self, key, row, calib_keys=None, noise=None):
        """Rotation-only between factor of two poses: ``key = (key_prev, key)``.

        ``wz * dt`` is the heading change between the two poses; the noise is ``sigma * dt``
        (rad). A ``gyro_bias`` key in ``calib_keys`` is honoured through a custom factor.
        """
        import gtsam

        k0, k1 = key
        dt = self._dt(row)
        z = float(self.z(row)[0])
        sigma = math.sqrt(self.R(row)[0, 0]) * dt
        nm = noise if noise is not None else gtsam.noiseModel.Isotropic.Sigma(1, sigma)
        bias_key = (calib_keys or {}).get("gyro_bias")
        keys = [k0, k1] + ([bias_key] if bias_key is not None else [])

        def error(this, values, jacobians):
            a, b = _pose_of(values, k0), _pose_of(values, k1)
            bias = _scalar_of(values, bias_key) if bias_key is not None else 0.0
            err = np.array([float(wrap(b[2] - a[2] + bias * dt - z * dt))])
            if jacobians is not None:
                jacobians[0] = np.array([[0.0, 0.0, -1.0]])
                jacobians[1] = np.array([[0.0, 0.0, 1.0]])
                if bias_key is not None:
                    jacobians[2] = np.array([[dt]])
            return err

        return gtsam.CustomFactor(nm, gtsam.KeyVector(keys), error)
