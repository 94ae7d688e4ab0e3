"""Models of map-based sensors: :class:`BeaconRange` (range to a known beacon, optional
scale/offset calibration), :class:`LandmarkBearing` and :class:`LandmarkRangeBearing`
(robot-frame bearing, range and bearing to a mapped landmark)."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from odofuse.measurements.base import (
    MeasurementModel,
    _landmark,
)
from odofuse.se2 import wrap


@dataclass(frozen=True)
class BeaconRange(MeasurementModel):
    """Range to a known beacon, ``h(x) = s * ||p - b|| + o`` (m).

    ``landmarks`` maps beacon id -> ``(2,)`` world position; rows hold ``id`` and ``range``.
    With ``calibrate`` the scale ``s`` (``range_scale``, nominal 1) and offset ``o``
    (``range_offset``, m, nominal 0) are augmented states, so a systematic range error of a
    few percent is learnt online instead of being absorbed into the pose.
    """

    landmarks: Mapping[int, np.ndarray] = field(default_factory=dict)
    calibrate: bool = False
    scale_sigma: float = 0.05
    offset_sigma: float = 0.5
    scale_walk: float = 0.0
    offset_walk: float = 0.0

    @property
    def calib_states(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("range_scale", "range_offset") if self.calibrate else ()

    def calib_prior(self):
        if not self.calibrate:
            return {}
        return {"range_scale": (1.0, self.scale_sigma), "range_offset": (0.0, self.offset_sigma)}

    def calib_walk(self):
        if not self.calibrate:
            return {}
        return {"range_scale": self.scale_walk, "range_offset": self.offset_walk}

    def z(self, row) -> np.ndarray:
        return np.array([float(row["range"])])

    # The EKF calls h and H once per range: the beacon lookup and the calibration indices
    # are prepared once per (bound) model, as plain floats and ints.
    @functools.cached_property
    def _beacons(self) -> dict[int, tuple[float, float]]:
        return {int(k): (float(v[0]), float(v[1])) for k, v in self.landmarks.items()}

    @functools.cached_property
    def _calib_cols(self) -> tuple[int | None, int | None]:
        return self.calib_index.get("range_scale"), self.calib_index.get("range_offset")

    def _geometry(self, x, row):
        b = _landmark(self._beacons, row, self.name)
        dx, dy = float(x[0]) - b[0], float(x[1]) - b[1]
        i_s, i_o = self._calib_cols
        n = len(x)
        i_s = i_s if i_s is not None and i_s < n else None
        i_o = i_o if i_o is not None and i_o < n else None
        return dx, dy, math.hypot(dx, dy), i_s, i_o

    def h(self, x, row) -> np.ndarray:
        _, _, d, i_s, i_o = self._geometry(x, row)
        scale = float(x[i_s]) if i_s is not None else 1.0
        offset = float(x[i_o]) if i_o is not None else 0.0
        return np.array([scale * d + offset])

    def h_many(self, X, row) -> np.ndarray:
        b = _landmark(self.landmarks, row, self.name)
        d = np.hypot(X[:, 0] - b[0], X[:, 1] - b[1])
        scale = self._get_many(X, "range_scale", 1.0)
        return (scale * d + self._get_many(X, "range_offset", 0.0))[:, None]

    def H(self, x, row) -> np.ndarray:
        dx, dy, d, i_s, i_o = self._geometry(x, row)
        d = max(d, 1e-9)
        scale = float(x[i_s]) if i_s is not None else 1.0
        J = np.zeros((1, len(x)))
        J[0, 0], J[0, 1] = scale * dx / d, scale * dy / d
        if i_s is not None:
            J[0, i_s] = d
        if i_o is not None:
            J[0, i_o] = 1.0
        return J

    def factor(self, key, row, calib_keys=None, noise=None, landmark_key=None):
        """Built-in ``RangeFactor2D(key, landmark_key)`` when the beacon is a graph variable
        (``landmark_key``, no calibration keys); otherwise a custom unary factor to the known
        beacon (GTSAM has no built-in unary range-to-point factor)."""
        import gtsam

        if landmark_key is not None and not calib_keys:
            return gtsam.RangeFactor2D(
                key, landmark_key, float(self.z(row)[0]), self.noise(row, noise)
            )
        keys = dict(calib_keys or {}) if self.calibrate else {}
        return range_factor(
            key,
            float(self.z(row)[0]),
            self.noise(row, noise),
            beacon=_landmark(self._beacons, row, self.name),
            scale_key=keys.get("range_scale"),
            offset_key=keys.get("range_offset"),
        )


def range_factor(
    pose_key, z, noise, beacon=None, landmark_key=None, scale_key=None, offset_key=None
):
    """``gtsam.CustomFactor`` of a range ``h = s ||p - l|| + o`` (m) from the pose ``p`` to a
    known beacon ``l`` (``beacon``, ``(x, y)``) or a landmark variable (``landmark_key``,
    ``Point2``; SLAM with range calibration: GTSAM's ``RangeFactor2D`` has no scale and
    ``RangeFactorWithTransformBias2D`` no scale), with optional scale ``s`` and offset ``o``
    variables (1-vectors; nominal 1 and 0 without their key).

    The error is ``h - z`` (GTSAM's sign); Jacobians are analytic, w.r.t. the Pose2 body
    tangent ``[v_x, v_y, omega]`` (``d p = R(theta) d v``), the landmark, ``s`` and ``o``: the
    same numbers as :meth:`MeasurementModel.factor` on :class:`BeaconRange`'s ``h`` and ``H``
    (distance floored at 1e-9 in the Jacobians), in scalars (Plaza1's smoother evaluates 3,527
    of them a dozen times).
    """
    import gtsam

    keys = [pose_key] + [k for k in (landmark_key, scale_key, offset_key) if k is not None]
    z = float(z)
    bx, by = (float(beacon[0]), float(beacon[1])) if beacon is not None else (0.0, 0.0)

    def error(this, values, H):
        p = values.atPose2(pose_key)
        if landmark_key is not None:
            bx_, by_ = values.atPoint2(landmark_key).tolist()
        else:
            bx_, by_ = bx, by
        s = float(values.atVector(scale_key)[0]) if scale_key is not None else 1.0
        o = float(values.atVector(offset_key)[0]) if offset_key is not None else 0.0
        dx, dy = p.x() - bx_, p.y() - by_
        d = math.hypot(dx, dy)
        if H is not None:
            dd = max(d, 1e-9)
            ux, uy = dx / dd, dy / dd
            th = p.theta()
            c, sn = math.cos(th), math.sin(th)
            H[0] = np.array([[s * (ux * c + uy * sn), s * (-ux * sn + uy * c), 0.0]])
            i = 1
            if landmark_key is not None:
                H[i] = np.array([[-s * ux, -s * uy]])
                i += 1
            if scale_key is not None:
                H[i] = np.array([[dd]])
                i += 1
            if offset_key is not None:
                H[i] = np.array([[1.0]])
        return np.array([s * d + o - z])

    return gtsam.CustomFactor(noise, gtsam.KeyVector(keys), error)


@dataclass(frozen=True)
class LandmarkBearing(MeasurementModel):
    """Bearing (robot frame, rad) to a mapped landmark: ``wrap(atan2(ly-y, lx-x) - theta)``."""

    landmarks: Mapping[int, np.ndarray] = field(default_factory=dict)

    angle_rows = (0,)

    def z(self, row) -> np.ndarray:
        return np.array([float(wrap(float(row["bearing"])))])

    def h(self, x, row) -> np.ndarray:
        b = _landmark(self.landmarks, row, self.name)
        return np.array([float(wrap(math.atan2(b[1] - x[1], b[0] - x[0]) - x[2]))])

    def h_many(self, X, row) -> np.ndarray:
        b = _landmark(self.landmarks, row, self.name)
        return wrap(np.arctan2(b[1] - X[:, 1], b[0] - X[:, 0]) - X[:, 2])[:, None]

    def H(self, x, row) -> np.ndarray:
        b = _landmark(self.landmarks, row, self.name)
        dx, dy = b[0] - x[0], b[1] - x[1]
        q = max(dx * dx + dy * dy, 1e-18)
        J = np.zeros((1, len(x)))
        J[0, 0], J[0, 1], J[0, 2] = dy / q, -dx / q, -1.0
        return J

    def factor(self, key, row, calib_keys=None, noise=None, landmark_key=None):
        """``BearingFactor2D(key, landmark_key)`` (built in) or a custom unary factor."""
        import gtsam

        if landmark_key is not None:
            return gtsam.BearingFactor2D(
                key, landmark_key, gtsam.Rot2(float(self.z(row)[0])), self.noise(row, noise)
            )
        return super().factor(key, row, calib_keys, noise)


@dataclass(frozen=True)
class LandmarkRangeBearing(MeasurementModel):
    """Range (m) and bearing (rad, robot frame) to a mapped landmark; ``dim = 2``.

    ``sigma`` is the range sigma, ``sigma_bearing`` the bearing sigma; rows hold ``id``,
    ``range``, ``bearing``. Rows that carry their own finite ``sigma_range`` and
    ``sigma_bearing`` (pose-graph files, docs/formats.md section 3) use those unless the
    sensor block sets a sigma (``file_noise`` false).
    """

    landmarks: Mapping[int, np.ndarray] = field(default_factory=dict)
    sigma_bearing: float = 0.02
    file_noise: bool = True

    dim = 2
    angle_rows = (1,)

    def z(self, row) -> np.ndarray:
        return np.array([float(row["range"]), float(wrap(float(row["bearing"])))])

    def h(self, x, row) -> np.ndarray:
        b = _landmark(self.landmarks, row, self.name)
        dx, dy = b[0] - x[0], b[1] - x[1]
        return np.array([math.hypot(dx, dy), float(wrap(math.atan2(dy, dx) - x[2]))])

    def h_many(self, X, row) -> np.ndarray:
        b = _landmark(self.landmarks, row, self.name)
        dx, dy = b[0] - X[:, 0], b[1] - X[:, 1]
        return np.column_stack([np.hypot(dx, dy), wrap(np.arctan2(dy, dx) - X[:, 2])])

    def H(self, x, row) -> np.ndarray:
        b = _landmark(self.landmarks, row, self.name)
        dx, dy = b[0] - x[0], b[1] - x[1]
        q = max(dx * dx + dy * dy, 1e-18)
        d = math.sqrt(q)
        J = np.zeros((2, len(x)))
        J[0, 0], J[0, 1] = -dx / d, -dy / d
        J[1, 0], J[1, 1], J[1, 2] = dy / q, -dx / q, -1.0
        return J

    def R(self, row) -> np.ndarray:
        if self.file_noise and row is not None and "sigma_range" in row and "sigma_bearing" in row:
            sr, sb = float(row["sigma_range"]), float(row["sigma_bearing"])
            if math.isfinite(sr) and math.isfinite(sb) and sr > 0 and sb > 0:
                return np.diag([sr * sr, sb * sb])
        return np.diag([self.sigma**2, self.sigma_bearing**2])

    def factor(self, key, row, calib_keys=None, noise=None, landmark_key=None):
        """``BearingRangeFactor2D(key, landmark_key)`` (built in) or a custom unary factor.

        A ``noise`` given for the built-in factor must be in GTSAM's (bearing, range) order.
        """
        import gtsam

        if landmark_key is not None:
            z = self.z(row)
            # GTSAM orders this measurement (bearing, range): swap R accordingly.
            R = self.R(row)[::-1, ::-1].copy()
            nm = noise if noise is not None else gtsam.noiseModel.Gaussian.Covariance(R)
            return gtsam.BearingRangeFactor2D(
                key, landmark_key, gtsam.Rot2(float(z[1])), float(z[0]), nm
            )
        return super().factor(key, row, calib_keys, noise)
