"""Models of absolute pose sensors: :class:`GpsPosition` (position fixes, local metres or
WGS-84 lat/lon) and :class:`CompassHeading` (heading)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from odofuse.measurements.base import (
    MeasurementModel,
)
from odofuse.se2 import wrap


@dataclass(frozen=True)
class GpsPosition(MeasurementModel):
    """GPS position fix of an antenna at ``lever_arm`` (body frame) on the robot.

    ``h(x) = p + R(theta) l`` (m, world frame), ``l = lever_arm``. A row holds either local
    ``x, y`` (m) or WGS-84 ``lat, lon`` (degrees) converted to east/north metres about
    ``datum = (lat0, lon0[, h0])`` with ``pymap3d.geodetic2enu``; an optional ``sigma``
    column (m) overrides ``sigma`` per fix.
    """

    lever_arm: tuple[float, float] = (0.0, 0.0)
    datum: tuple[float, ...] | None = None

    dim = 2

    def z(self, row) -> np.ndarray:
        if "x" in row and "y" in row:
            return np.array([float(row["x"]), float(row["y"])])
        if "lat" in row and "lon" in row:
            if self.datum is None:
                raise ValueError(
                    f"stream '{self.name}' holds lat/lon but the sensor block has no 'datum'"
                )
            import pymap3d

            lat0, lon0 = float(self.datum[0]), float(self.datum[1])
            h0 = float(self.datum[2]) if len(self.datum) > 2 else 0.0
            e, n, _ = pymap3d.geodetic2enu(float(row["lat"]), float(row["lon"]), h0, lat0, lon0, h0)
            return np.array([float(e), float(n)])
        raise ValueError(f"stream '{self.name}' needs columns x, y or lat, lon; got {sorted(row)}")

    def h(self, x, row=None) -> np.ndarray:
        lx, ly = self.lever_arm
        c, s = math.cos(x[2]), math.sin(x[2])
        return np.array([x[0] + c * lx - s * ly, x[1] + s * lx + c * ly])

    def h_many(self, X, row=None) -> np.ndarray:
        lx, ly = self.lever_arm
        c, s = np.cos(X[:, 2]), np.sin(X[:, 2])
        return np.column_stack([X[:, 0] + c * lx - s * ly, X[:, 1] + s * lx + c * ly])

    def H(self, x, row=None) -> np.ndarray:
        lx, ly = self.lever_arm
        c, s = math.cos(x[2]), math.sin(x[2])
        J = np.zeros((2, len(x)))
        J[0, 0] = J[1, 1] = 1.0
        J[0, 2] = -s * lx - c * ly
        J[1, 2] = c * lx - s * ly
        return J

    def factor(self, key, row, calib_keys=None, noise=None):
        """``PoseTranslationPrior2D`` (built in) without a lever arm, else a custom factor."""
        import gtsam

        if self.lever_arm[0] == 0.0 and self.lever_arm[1] == 0.0:
            return gtsam.PoseTranslationPrior2D(key, self.z(row), self.noise(row, noise))
        return super().factor(key, row, calib_keys, noise)


@dataclass(frozen=True)
class CompassHeading(MeasurementModel):
    """Absolute heading ``h(x) = theta + offset`` (rad); optional ``compass_offset`` state."""

    calibrate: bool = False
    offset_sigma: float = 0.1

    angle_rows = (0,)

    @property
    def calib_states(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("compass_offset",) if self.calibrate else ()

    def calib_prior(self):
        return {"compass_offset": (0.0, self.offset_sigma)} if self.calibrate else {}

    def z(self, row) -> np.ndarray:
        return np.array([float(wrap(float(row["heading"])))])

    def h(self, x, row=None) -> np.ndarray:
        return np.array([float(wrap(x[2] + self._get(x, "compass_offset", 0.0)))])

    def h_many(self, X, row=None) -> np.ndarray:
        return wrap(X[:, 2] + self._get_many(X, "compass_offset", 0.0))[:, None]

    def H(self, x, row=None) -> np.ndarray:
        J = np.zeros((1, len(x)))
        J[0, 2] = 1.0
        c = self._col("compass_offset", len(x))
        if c is not None:
            J[0, c] = 1.0
        return J

    def factor(self, key, row, calib_keys=None, noise=None):
        """``PoseRotationPrior2D`` (built in) unless the offset is estimated."""
        import gtsam

        if not (calib_keys and "compass_offset" in calib_keys):
            rot = gtsam.Pose2(0.0, 0.0, float(self.z(row)[0]))
            return gtsam.PoseRotationPrior2D(key, rot, self.noise(row, noise))
        return super().factor(key, row, calib_keys, noise)
