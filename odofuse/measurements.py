"""Measurement models: one interface for every exteroceptive/proprioceptive sensor.

Each model maps the filter state ``x`` (``x[:3]`` the world pose ``[x, y, theta]``,
``x[3:]`` augmented calibration/clone states) and one stream row to a predicted measurement
``h(x, row)``, its analytic Jacobian ``H(x, row)`` of shape ``(dim, len(x))``, the noise
``R(row)`` and an angle-aware ``residual(z, z_hat)``. The same model also yields a GTSAM
factor (``factor``) so the Kalman filters and the factor graph share one definition.

Augmented states
----------------
A model lists the names of the augmented states it reads in ``calib_states`` (for example
``("range_scale", "range_offset")``). The filter appends all names used by the run's models
after ``[x, y, theta]`` in first-seen order, then hands each model the name -> index map with
:meth:`MeasurementModel.bind`. An unbound model (or a state missing from the map) uses the
state's nominal value (scale 1, offsets and biases 0), so ``h`` also works on a bare pose.
``calib_prior()`` gives each state's initial value and standard deviation and
``calib_walk()`` its random-walk density (units per sqrt(s)).

Models
------
``GpsPosition`` (local metres or WGS-84 lat/lon converted to ENU about a datum, optional
antenna lever arm), ``GyroYawRate`` (yaw rate against the heading change since the previous
gyro sample, via a cloned heading state), ``CompassHeading``, ``BeaconRange`` (range to a
known beacon, optional scale/offset calibration), ``LandmarkBearing`` and
``LandmarkRangeBearing`` (robot-frame range and bearing to a mapped landmark). The geometry
is the head-to-tail composition of ``002_88fc37db58155723.txt`` and the rotation
``R(theta)`` of Siegwart & Nourbakhsh ch. 3 (``004_f4547100a083f338.txt``).

User models are named in the sensor block as ``class: "package.module:Class"``; the class is
called as ``Class(name=stream, **keys)`` (plus ``landmarks=`` the map when it takes that
keyword; ``class``, ``gate`` and ``robust`` are not passed) and must provide the attributes
and methods of :class:`MeasurementModel`. A class that declares its keys as a frozen dataclass
``Options`` (fields made with :func:`odofuse.options.option`) gets them validated and
default-filled; otherwise its keys are passed unchecked.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from odofuse.declarations import STREAM_DEFAULTS, LoopClosureOptions, PluginSensorOptions
from odofuse.errors import ConfigError, InputError
from odofuse.options import explicit
from odofuse.se2 import wrap

__all__ = [
    "MeasurementModel",
    "GpsPosition",
    "GyroYawRate",
    "CompassHeading",
    "BeaconRange",
    "LandmarkBearing",
    "LandmarkRangeBearing",
    "MODELS",
    "STREAM_DEFAULTS",
    "measurement_models",
    "gate_threshold",
    "wrap",
]


def gate_threshold(probability: float | None, dim: int) -> float:
    """Chi-square gate on the normalised innovation squared (NIS).

    Parameters
    ----------
    probability : float or None
        Acceptance probability in (0, 1); ``None`` disables the gate (``inf``).
    dim : int
        Measurement dimension (degrees of freedom).

    Returns
    -------
    float
        ``chi2.ppf(probability, dim)``: a measurement with ``y^T S^-1 y`` above it is rejected.
    """
    if probability is None:
        return math.inf
    from odofuse import chi2

    return float(chi2.ppf(float(probability), int(dim)))


def _body_jacobian(H_pose: np.ndarray, theta: float) -> np.ndarray:
    """Convert a Jacobian w.r.t. world ``[x, y, theta]`` to GTSAM's Pose2 body tangent.

    ``Pose2.retract(xi)`` moves the position by ``R(theta) xi[:2]`` and the heading by
    ``xi[2]``, so ``dh/dxi = H_world @ blockdiag(R(theta), 1)``.
    """
    c, s = math.cos(theta), math.sin(theta)
    T = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return H_pose @ T


def _pose_of(values, key) -> np.ndarray:
    p = values.atPose2(key)
    return np.array([p.x(), p.y(), p.theta()])


def _scalar_of(values, key) -> float:
    return float(np.asarray(values.atVector(key)).reshape(-1)[0])


@dataclass(frozen=True)
class MeasurementModel:
    """Base class of the built-in models (a user model may duck-type it instead).

    Attributes
    ----------
    name : str
        Stream name (``"ranges"``).
    sigma : float
        Standard deviation of the (first) measured quantity, in its unit.
    gate : float or None
        Chi-square acceptance probability of the innovation gate; ``None`` = no gate.
    calib_index : Mapping[str, int]
        Where each augmented state sits in the filter state (set by :meth:`bind`).
    """

    name: str = ""
    sigma: float = 1.0
    gate: float | None = 0.999
    calib_index: Mapping[str, int] = field(default_factory=dict)

    dim = 1
    calib_states = ()
    angle_rows = ()

    # -- augmented states -------------------------------------------------------------
    def bind(self, index: Mapping[str, int]) -> MeasurementModel:
        """A copy that reads its augmented states at ``index[name]`` of the filter state."""
        return dataclasses.replace(self, calib_index=dict(index))

    def calib_prior(self) -> dict[str, tuple[float, float]]:
        """``{state: (initial value, initial sigma)}`` for each name in ``calib_states``."""
        return {}

    def calib_walk(self) -> dict[str, float]:
        """``{state: random-walk sigma per sqrt(second)}``; 0 for a constant."""
        return {s: 0.0 for s in self.calib_states}

    def clones(self) -> dict[str, int]:
        """Augmented states that the filter resets to a copy of state ``i`` after each update."""
        return {}

    def _get(self, x, state: str, default: float) -> float:
        i = self.calib_index.get(state)
        return float(x[i]) if i is not None and i < len(x) else default

    def _col(self, state: str, n: int) -> int | None:
        i = self.calib_index.get(state)
        return i if i is not None and i < n else None

    # -- the interface ----------------------------------------------------------------
    def z(self, row: Mapping[str, float]) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def h(self, x, row) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def H(self, x, row) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def h_many(self, X, row) -> np.ndarray:
        """``h`` of many states ``X`` (N, n) at once, shape (N, dim) (particle filter)."""
        return np.array([self.h(x, row) for x in np.asarray(X, dtype=float)])

    def _get_many(self, X, state: str, default: float):
        i = self.calib_index.get(state)
        return X[:, i] if i is not None and i < X.shape[1] else default

    def R(self, row) -> np.ndarray:
        """Measurement covariance ``(dim, dim)``: ``sigma^2`` (or the row's ``sigma``).

        Without a per-row ``sigma`` the same (read-only) array is returned every time.
        """
        if row is not None and "sigma" in row:
            s = float(row["sigma"])
            return np.eye(self.dim) * (s * s)
        return self._R_const

    @functools.cached_property
    def _R_const(self) -> np.ndarray:
        R = np.eye(self.dim) * (self.sigma * self.sigma)
        R.flags.writeable = False
        return R

    def residual(self, z, z_hat) -> np.ndarray:
        """``z - z_hat`` with the rows in ``angle_rows`` wrapped to ``[-pi, pi)``."""
        d = np.atleast_1d(np.asarray(z, dtype=float) - np.asarray(z_hat, dtype=float)).copy()
        for r in self.angle_rows:
            d[r] = wrap(d[r])
        return d

    def mean(self, Z, weights) -> np.ndarray:
        """Weighted mean of predicted measurements ``Z`` ``(m, dim)`` (circular for angles)."""
        Z = np.asarray(Z, dtype=float)
        w = np.asarray(weights, dtype=float)
        m = w @ Z
        for r in self.angle_rows:
            m[r] = math.atan2(w @ np.sin(Z[:, r]), w @ np.cos(Z[:, r]))
        return m

    # -- GTSAM ------------------------------------------------------------------------
    def noise(self, row, noise=None):
        """The GTSAM noise model of one row (``noise`` overrides)."""
        import gtsam

        if noise is not None:
            return noise
        return gtsam.noiseModel.Gaussian.Covariance(self.R(row))

    def factor(self, key, row, calib_keys: Mapping[str, int] | None = None, noise=None):
        """A ``gtsam.CustomFactor`` on pose ``key`` (+ calibration keys, scalar Vector values).

        The error is ``h(x) - z`` (GTSAM's sign), whitened by ``R(row)``; Jacobians are the
        analytic ``H`` moved to the Pose2 body tangent. ``calib_keys`` maps augmented state
        names to GTSAM keys holding 1-vectors; states without a key take nominal values.
        """
        import gtsam

        calib_keys = dict(calib_keys or {})
        names = [s for s in self.calib_states if s in calib_keys]
        keys = [key] + [calib_keys[s] for s in names]
        bound = self.bind({s: 3 + i for i, s in enumerate(names)})
        z = self.z(row)

        def error(this, values, jacobians):
            x = np.concatenate([_pose_of(values, key), [_scalar_of(values, k) for k in keys[1:]]])
            err = -bound.residual(z, bound.h(x, row))
            if jacobians is not None:
                Hx = bound.H(x, row)
                jacobians[0] = _body_jacobian(Hx[:, :3], x[2])
                for i in range(len(names)):
                    jacobians[1 + i] = Hx[:, 3 + i : 4 + i].copy()
            return err

        return gtsam.CustomFactor(self.noise(row, noise), gtsam.KeyVector(keys), error)


def _landmark(landmarks: Mapping[int, np.ndarray], row, stream: str):
    """Map position of the row's ``id`` (an ``(2,)`` array or pair), InputError if unknown."""
    lid = int(round(float(row["id"])))
    try:
        return landmarks[lid]
    except KeyError:
        ids = sorted(landmarks)
        known = ", ".join(map(str, ids[:10])) + (", ..." if len(ids) > 10 else "")
        raise InputError(
            f"stream '{stream}' at t={row.get('t', float('nan')):.6f}: landmark id {lid} "
            f"is not in the map (known ids: {known or 'none'})",
            column="id",
        ) from None


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
        return np.array([float(wrap(x[2] - ref)) / dt + self._get(x, "gyro_bias", 0.0)])

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
        return super().factor(key, row, calib_keys, noise)


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


#: Built-in model classes by name (the sensor block's ``model`` key).
MODELS: dict[str, type] = {
    "gps": GpsPosition,
    "gyro": GyroYawRate,
    "compass": CompassHeading,
    "range": BeaconRange,
    "bearing": LandmarkBearing,
    "range_bearing": LandmarkRangeBearing,
}

_LANDMARK_MODELS = ("range", "bearing", "range_bearing")
# Sensor options that are not fields of the model (read by the estimators, or aliases).
_NOT_MODEL_FIELDS = ("model", "robust", "gyrodometry", "threshold", "sigma_range")


def _accepts(cls, name: str) -> bool:
    """Whether ``cls(...)`` takes keyword ``name`` (or ``**kwargs``)."""
    import inspect

    try:
        params = inspect.signature(cls).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name == name or p.kind is p.VAR_KEYWORD for p in params)


def _build_plugin(stream: str, opts: PluginSensorOptions, landmarks, source: str):
    prefix, spec, cls = f"sensors.{stream}", opts.spec, opts.cls
    params = opts.params
    kwargs = dict(
        {f.name: getattr(params, f.name) for f in dataclasses.fields(params)}
        if dataclasses.is_dataclass(params)
        else params,
        name=stream,
    )
    if _accepts(cls, "landmarks"):
        kwargs["landmarks"] = landmarks
    try:
        model = cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"cannot build {spec}: {exc}", source, f"{prefix}.class") from None
    if hasattr(model, "gate") and dataclasses.is_dataclass(model):
        try:
            model = dataclasses.replace(model, gate=opts.gate)
        except (TypeError, ValueError):
            pass
    for attr in ("dim", "z", "h", "H", "R", "residual"):
        if not hasattr(model, attr):
            raise ConfigError(
                f"{spec} lacks '{attr}' of the MeasurementModel interface",
                source,
                f"{prefix}.class",
            )
    return model


def _build_one(stream: str, opts, landmarks, source: str):
    """The model of stream ``stream`` from its validated sensor options."""
    if isinstance(opts, PluginSensorOptions):
        return _build_plugin(stream, opts, landmarks, source)
    kind = opts.kind
    kwargs = {
        f.name: getattr(opts, f.name)
        for f in dataclasses.fields(opts)
        if f.name not in _NOT_MODEL_FIELDS
    }
    if getattr(opts, "sigma_range", None) is not None:
        kwargs["sigma"] = opts.sigma_range
    kwargs["name"] = stream
    if kind == "range_bearing" and {"sigma", "sigma_range", "sigma_bearing"} & explicit(opts):
        kwargs["file_noise"] = False  # the config's sigmas override the file's
    if kind in _LANDMARK_MODELS:
        if not landmarks:
            raise ConfigError(
                f"a '{kind}' sensor needs a map (map.csv) of landmark positions",
                source,
                f"sensors.{stream}",
            )
        kwargs["landmarks"] = {int(i): np.asarray(p, dtype=float) for i, p in landmarks.items()}
    return MODELS[kind](**kwargs)


def measurement_models(config, log=None) -> dict[str, MeasurementModel]:
    """Build the run's measurement models from ``config.sensors``.

    Parameters
    ----------
    config : RunConfig
        ``sensors`` maps a stream name to its validated options
        (:data:`odofuse.declarations.SENSOR_OPTIONS`, one class per model kind, chosen by the
        block's ``model`` or the stream name, :data:`STREAM_DEFAULTS`; or a
        ``class: "package.module:Class"`` plug-in). Keys used by the estimators
        (``gyrodometry``, ``threshold``, ``robust``) are not passed to the models.
    log : SensorLog, optional
        Supplies the landmark map, and the first fix of a lat/lon GPS stream as its datum
        when the sensor block sets none.

    Returns
    -------
    dict
        Stream name -> model, in the config's order; streams absent from ``log`` are kept
        (the estimator skips them).

    Raises
    ------
    ConfigError
        Naming ``sensors.<stream>.<key>`` and ``config.source``.
    """
    source = getattr(config, "source", "<config>")
    landmarks = dict(getattr(log, "landmarks", {}) or {})
    models = {
        s: _build_one(s, b, landmarks, source)
        for s, b in config.sensors.items()
        if not isinstance(b, LoopClosureOptions)  # read by the graph estimators, not a model
    }
    # A lat/lon GPS stream without a datum is expressed about its first fix (the usual default
    # of robot_localization's navsat_transform when no datum is set).
    streams = getattr(log, "streams", {}) or {}
    for name, model in models.items():
        stream = streams.get(name)
        if (
            isinstance(model, GpsPosition)
            and model.datum is None
            and stream is not None
            and len(stream)
            and {"lat", "lon"} <= set(stream.columns)
        ):
            models[name] = dataclasses.replace(
                model, datum=(float(stream["lat"][0]), float(stream["lon"][0]))
            )
    return models
