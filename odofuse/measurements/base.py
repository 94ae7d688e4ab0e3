"""The measurement-model interface: :class:`MeasurementModel` and what every model shares.

Owns the base class (``h``, ``H``, ``R``, ``residual``, ``z``, the augmented-state binding
``bind`` and the default GTSAM ``factor``), the chi-square gate :func:`gate_threshold`, the
body-frame Jacobian conversion for GTSAM and the landmark lookup of the map-based models.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from odofuse.errors import InputError
from odofuse.se2 import wrap


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
