"""GTSAM factor-graph back end: batch smoother, iSAM2 and a fixed-lag smoother.

The graph is built from the run's single :class:`odofuse.motion.MotionModel` and its
:mod:`odofuse.measurements` models, so it cannot drift apart from the filters:

* **Keyframes** at every sensor time (ranges, GPS, ...), every ``keyframe_dt`` seconds and,
  optionally, every ``keyframe_ds`` metres / ``keyframe_dtheta`` radians of odometry (or at
  every odometry row with ``keyframe_every_step``). An odometry step straddling a keyframe is
  split: its wheel / increment inputs are scaled by the time fraction (steering angles are
  held), which is exact for the constant-twist step of the ``exact`` integrator.
* **Odometry factors**: the steps between two keyframes are pre-integrated with
  ``MotionModel.relative`` (Siegwart error model, ``004_f4547100a083f338.txt`` ch. 5; head-to-tail
  composition, ``002_88fc37db58155723.txt``) into a ``BetweenFactorPose2`` whose covariance is
  already in GTSAM's body (tangent) convention.
* **Sensor factors** come from each model's ``factor`` (built-in ``PoseTranslationPrior2D``,
  ``RangeFactor2D``, ``BearingRangeFactor2D``, ... where GTSAM has one), wrapped in a
  Huber / Cauchy / Tukey loss per stream. Calibration states of the models (range scale and
  offset, gyro bias, compass offset) become graph variables with the models' priors.
* **Landmarks**: known (a tightly fixed ``Point2`` variable per map entry, or the model's unary
  factor when calibration variables are involved) or unknown (``slam: true``: a variable per
  id, initialised by a robust grid search of the ranges against the dead-reckoned path).

Solvers: batch Levenberg-Marquardt (:func:`run_smoother`), iSAM2 one update per keyframe
(:func:`run_isam2`) and GTSAM's ``IncrementalFixedLagSmoother`` (:func:`run_fixed_lag`).
Marginal covariances are converted to the world frame with :func:`odofuse.se2.cov_body_to_world`.
Options are documented in ``docs/graph.md``.
"""

from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass, field

import numpy as np

from odofuse import se2
from odofuse.declarations import ROBUST_KINDS  # noqa: F401 - re-exported
from odofuse.declarations import robust_loss as _robust_entry
from odofuse.errors import ConfigError
from odofuse.estimators.common import initial_state, odometry_inputs, odometry_stream_name
from odofuse.estimators.graph_factors import (
    calibrated_between_factor,
    frozen_calibration_factor,
    levenberg_marquardt,
    range_landmark_factor,
    robust_noise,
)
from odofuse.trajectory import EstimateResult, Trajectory

__all__ = [
    "GraphOptions",
    "GraphProblem",
    "parse_options",
    "keyframe_times",
    "preintegrate",
    "build_problem",
    "build_graph",
    "slam_initial_landmarks",
    "run_smoother",
    "run_isam2",
    "run_fixed_lag",
]

#: Option keys accepted in ``options.<smoother|isam2|fixed_lag>``.
OPTION_KEYS = (
    "keyframe_dt",
    "keyframe_ds",
    "keyframe_dtheta",
    "keyframe_every_step",
    "robust",
    "slam",
    "lag",
    "max_iterations",
    "relative_tolerance",
    "covariances",
    "slam_grid",
    "known_landmark_sigma",
    "relinearize_threshold",
    "relinearize_skip",
    "odometry_floor",
    "final_relinearizations",
    "odometry_calibration",
    "calibration_freeze",
)
LANDMARK_SENSORS = ("BeaconRange", "LandmarkBearing", "LandmarkRangeBearing")
# Variance (m^2, rad^2) added to every pre-integrated covariance so that a single step of a
# drive with a rank-deficient input covariance (e.g. increments: no lateral noise) stays
# invertible: a 0.1 mm / 0.1 mrad floor per keyframe interval, below any odometry noise.
_COV_FLOOR = 1e-8


def _X(i: int) -> int:
    import gtsam

    return gtsam.symbol("x", int(i))


def _L(i: int) -> int:
    import gtsam

    return gtsam.symbol("l", int(i))


def _B(i: int) -> int:
    import gtsam

    return gtsam.symbol("b", int(i))


def _C(i: int) -> int:
    import gtsam

    return gtsam.symbol("c", int(i))


# --------------------------------------------------------------------------- options
@dataclass(frozen=True)
class GraphOptions:
    """Validated options of a graph estimator (see ``docs/graph.md``).

    Attributes
    ----------
    keyframe_dt : float
        s; a keyframe at least this often (0 disables the time trigger).
    keyframe_ds, keyframe_dtheta : float
        m / rad of odometry travel between keyframes (0 disables).
    keyframe_every_step : bool
        A keyframe at every odometry row (the odometry-only graph then equals dead reckoning).
    robust : dict
        Stream -> ``(kind, k)`` with kind in ``huber|cauchy|tukey|none`` and ``k`` in sigma.
    slam : bool
        Landmarks are unknown graph variables.
    lag : float
        s, the window of the fixed-lag smoother.
    max_iterations, relative_tolerance :
        Levenberg-Marquardt stopping rule.
    covariances : bool
        Compute marginal covariances (world frame).
    slam_grid : float
        m, cell of the landmark initialisation grid.
    known_landmark_sigma : float
        m, sigma of the prior that pins a known landmark variable.
    calibration_freeze : dict or None
        ``isam2`` only, one of two forms. Absolute thresholds
        ``{"sigma": {state: threshold}, "check_every": n}``: every ``n`` updates the marginal
        sigma of each named calibration state is checked; once all the states of a sensor are
        below their thresholds, that sensor's later factors use the current estimate as
        constants (see :func:`run_isam2`). Convergence ``{"rel_change": r, "window": W [s],
        "min_time": T [s], "check_every": n}``: a sensor is frozen once each of its
        calibration sigmas shrank by less than the fraction ``r`` over the last ``W`` s of
        log time (with at least one new factor of the sensor in that window) and at least
        ``T`` s have elapsed since the first keyframe.
    """

    keyframe_dt: float = 1.0
    keyframe_ds: float = 0.0
    keyframe_dtheta: float = 0.0
    keyframe_every_step: bool = False
    robust: dict = field(default_factory=dict)
    slam: bool = False
    lag: float = 10.0
    max_iterations: int = 100
    relative_tolerance: float = 1e-6
    covariances: bool = True
    slam_grid: float = 1.0
    known_landmark_sigma: float = 1e-6
    relinearize_threshold: float = 0.1
    relinearize_skip: int = 10
    odometry_floor: float = 1e-8
    final_relinearizations: int = 3
    odometry_calibration: object = False
    calibration_freeze: dict | None = None


def _nonneg_option(value, key, source) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"expected a number, got {value!r}", file=source, key=key) from None
    if not (math.isfinite(v) and v >= 0.0):
        raise ConfigError(f"must be a non-negative number, got {value!r}", file=source, key=key)
    return v


def _bool_option(value, key, source) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"expected true or false, got {value!r}", file=source, key=key)
    return value


def _freeze_option(value, key, source, estimator) -> dict:
    """Validate ``calibration_freeze`` (isam2 only) into one of two forms.

    Absolute thresholds: ``{sigma: {state: positive float}, check_every: n}``.
    Convergence: ``{rel_change: r, window: W, min_time: T, check_every: n}`` with
    ``0 < r < 1``, ``W > 0`` s of log time and ``T >= 0`` s (default 0). Exactly one of
    ``sigma`` and ``rel_change`` must be given.
    """
    if estimator != "isam2":
        raise ConfigError("only the isam2 estimator freezes calibration states", source, key)
    form = "{sigma: {state: threshold}} or {rel_change: r, window: s}"
    if not isinstance(value, dict):
        raise ConfigError(f"expected {form}, got {value!r}", source, key)
    allowed = ("sigma", "rel_change", "window", "min_time", "check_every")
    bad = set(value) - set(allowed)
    if bad:
        raise ConfigError(
            f"unknown key; allowed: {', '.join(allowed)}", source, f"{key}.{min(bad, key=str)}"
        )
    every = value.get("check_every", 10)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError(
            f"expected a positive integer, got {every!r}", source, f"{key}.check_every"
        )
    if "sigma" in value and "rel_change" in value:
        raise ConfigError(
            "give either sigma (absolute thresholds) or rel_change (convergence), not both",
            source,
            f"{key}.rel_change",
        )
    if "sigma" in value:
        for extra in ("window", "min_time"):
            if extra in value:
                raise ConfigError("only with rel_change", source, f"{key}.{extra}")
        if not isinstance(value["sigma"], dict):
            raise ConfigError(
                f"expected {{state: threshold}}, got {value['sigma']!r}", source, f"{key}.sigma"
            )
        sigma = {}
        for state, v in value["sigma"].items():
            sigma[str(state)] = _nonneg_option(v, f"{key}.sigma.{state}", source)
            if sigma[str(state)] == 0.0:
                raise ConfigError("must be positive", source, f"{key}.sigma.{state}")
        return {"sigma": sigma, "check_every": every}
    if "rel_change" not in value:
        raise ConfigError(f"expected {form}, got {value!r}", source, key)
    rel = _nonneg_option(value["rel_change"], f"{key}.rel_change", source)
    if not 0.0 < rel < 1.0:
        raise ConfigError(
            f"must be a fraction in (0, 1), got {value['rel_change']!r}",
            source,
            f"{key}.rel_change",
        )
    if "window" not in value:
        raise ConfigError("required with rel_change (s of log time)", source, f"{key}.window")
    window = _nonneg_option(value["window"], f"{key}.window", source)
    if window == 0.0:
        raise ConfigError("must be positive", source, f"{key}.window")
    min_time = _nonneg_option(value.get("min_time", 0.0), f"{key}.min_time", source)
    return {"rel_change": rel, "window": window, "min_time": min_time, "check_every": every}


def parse_options(config, estimator: str) -> GraphOptions:
    """Validate ``config.options[estimator]`` into :class:`GraphOptions`.

    ``robust`` is either one loss for every sensor (``huber`` or ``{type: cauchy, k: 2}``) or
    a mapping stream -> loss (``{ranges: {type: huber, k: 1.345}, gps: cauchy}``). A sensor's
    own block may carry it too (``sensors: {ranges: {sigma: 0.5, robust: huber}}``); the option
    block wins where both name a stream.

    Raises
    ------
    ConfigError
        For an unknown key or a bad value, naming ``options.<estimator>.<key>`` and the file.
    """
    source = getattr(config, "source", "<config>")
    block = dict(config.estimator_options(estimator).values)
    prefix = f"options.{estimator}"
    kw: dict = {}
    per_sensor = {
        s: b.robust for s, b in config.sensors.items() if getattr(b, "robust", None) is not None
    }
    for key, value in block.items():
        k = f"{prefix}.{key}"
        if key not in OPTION_KEYS:
            raise ConfigError(
                f"unknown option; allowed: {', '.join(OPTION_KEYS)}", file=source, key=k
            )
        if key in ("keyframe_dt", "keyframe_ds", "keyframe_dtheta", "relative_tolerance"):
            kw[key] = _nonneg_option(value, k, source)
        elif key in ("lag", "slam_grid", "known_landmark_sigma"):
            v = _nonneg_option(value, k, source)
            if v == 0.0:
                raise ConfigError("must be positive", file=source, key=k)
            kw[key] = v
        elif key in ("keyframe_every_step", "slam", "covariances"):
            kw[key] = _bool_option(value, k, source)
        elif key in ("relinearize_threshold", "odometry_floor"):
            kw[key] = _nonneg_option(value, k, source)
        elif key in ("max_iterations", "relinearize_skip", "final_relinearizations"):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"expected a positive integer, got {value!r}", source, k)
            kw[key] = value
        elif key == "odometry_calibration":
            if not isinstance(value, bool | list):
                raise ConfigError(
                    f"expected true, false or a list of prior sigmas, got {value!r}", source, k
                )
            kw[key] = value
        elif key == "calibration_freeze":
            kw[key] = _freeze_option(value, k, source, estimator)
        elif key == "robust":
            streams = set(getattr(config, "sensors", {}) or {}) | {"odometry", "wheels"}
            if isinstance(value, dict) and (set(value) - {"type", "k"}):
                kw[key] = {s: _robust_entry(v, f"{k}.{s}", source) for s, v in value.items()}
                bad = set(kw[key]) - streams
                if bad:
                    raise ConfigError(
                        f"robust loss for stream(s) not in sensors: {', '.join(sorted(bad))}",
                        file=source,
                        key=f"{k}.{sorted(bad)[0]}",
                    )
            else:
                entry = _robust_entry(value, k, source)
                kw[key] = {s: entry for s in streams - {"odometry", "wheels"}}
    if per_sensor:
        kw["robust"] = {**per_sensor, **kw.get("robust", {})}
    return GraphOptions(**kw)


# --------------------------------------------------------------------------- odometry
def keyframe_times(t_odo, U, model, sensor_times, options: GraphOptions) -> np.ndarray:
    """Keyframe times: the odometry span's ends, sensor times and the dt/ds/dtheta triggers.

    Parameters
    ----------
    t_odo : ndarray (N+1,)
        Times of the poses of the odometry steps (s).
    U : ndarray (N, n)
        Drive inputs per step.
    model : MotionModel
    sensor_times : ndarray (M,)
        Times of the sensor rows that get a factor (inside ``[t_odo[0], t_odo[-1]]``).
    options : GraphOptions

    Returns
    -------
    ndarray (K,)
        Strictly increasing keyframe times (s).
    """
    t0, t1 = float(t_odo[0]), float(t_odo[-1])
    parts = [np.array([t0, t1]), np.asarray(sensor_times, dtype=float)]
    if options.keyframe_every_step:
        parts.append(t_odo)
    if options.keyframe_dt > 0:
        parts.append(np.arange(t0, t1, options.keyframe_dt))
    if (options.keyframe_ds > 0 or options.keyframe_dtheta > 0) and len(U):
        delta, _ = model.increment(U)
        for col, step in ((None, options.keyframe_ds), (2, options.keyframe_dtheta)):
            if step <= 0:
                continue
            inc = np.hypot(delta[:, 0], delta[:, 1]) if col is None else np.abs(delta[:, 2])
            cum = np.concatenate([[0.0], np.cumsum(inc)])
            bucket = np.floor(cum / step)
            parts.append(t_odo[1:][np.diff(bucket) > 0])
    return np.unique(np.concatenate(parts))


def preintegrate(t_odo, U, model, kt, odometry_calibration=None):
    """Relative poses and body-frame covariances between consecutive keyframes.

    Odometry step ``k`` spans ``(t_odo[k], t_odo[k+1]]``; a step cut by a keyframe is split
    into pieces whose wheel / increment inputs are scaled by their time fraction.

    Returns
    -------
    deltas : ndarray (K-1, 3)
        ``[dx, dy, dtheta]`` of keyframe ``i+1`` in the frame of keyframe ``i``.
    covs : ndarray (K-1, 3, 3)
        Their covariances in GTSAM's ``Pose2`` tangent convention (``MotionModel.relative``).
    G : ndarray (K-1, 3, m)
        Only with ``odometry_calibration`` (an :class:`OdometryCalibration`): the tangent
        change of each relative pose per unit change of the calibration parameters.
    """
    t_odo = np.asarray(t_odo, dtype=float)
    kt = np.asarray(kt, dtype=float)
    breaks = np.unique(np.concatenate([t_odo, kt]))
    breaks = breaks[(breaks >= kt[0]) & (breaks <= kt[-1])]
    a, b = breaks[:-1], breaks[1:]
    step = np.clip(np.searchsorted(t_odo, b, side="left") - 1, 0, len(U) - 1)
    frac = (b - a) / np.maximum(t_odo[step + 1] - t_odo[step], 1e-300)
    kinds = getattr(model.drive, "input_kinds", ("wheel",) * U.shape[1])
    scaled = np.array([kind != "steer" for kind in kinds])
    pieces = np.where(scaled, U[step] * frac[:, None], U[step])
    owner = np.searchsorted(kt, b, side="left") - 1  # keyframe interval of each piece
    if odometry_calibration is None:
        return _preintegrate_pieces(model, pieces, owner, len(kt) - 1)
    D = odometry_calibration.input_jacobian(pieces, b - a)
    return _preintegrate_pieces(model, pieces, owner, len(kt) - 1, D)


def _preintegrate_pieces(model, pieces, owner, n_intervals, D=None):
    """Vectorised ``MotionModel.relative`` of every keyframe interval at once.

    The body-frame (GTSAM tangent) covariance obeys, piece by piece,
    ``Sigma <- Ad(inc^-1) Sigma Ad(inc^-1)^T + T J Sigma_u J^T T^T`` with ``J = J_delta_u`` (the
    increment's Jacobian in the start frame) and ``T = blockdiag(R(dtheta)^T, 1)`` moving that
    noise into the tangent at the piece's end; the same first-order propagation as the
    world-frame recursion of ``dead_reckon`` followed by ``se2.cov_world_to_body`` (tested
    equal to ``MotionModel.relative``). Intervals run in parallel, padded with identity pieces.
    With ``D`` ``(P, n, m)`` (input change per unit calibration parameter) the sensitivity
    ``G <- Ad(inc^-1) G + T J D`` is accumulated by the same recursion and returned third.
    """
    deltas = np.zeros((n_intervals, 3))
    covs = np.zeros((n_intervals, 3, 3))
    G = None if D is None else np.zeros((n_intervals, 3, D.shape[2]))
    if len(pieces) == 0:
        return (deltas, covs) if D is None else (deltas, covs, G)
    inc, J = model.increment(pieces)
    var = model.errors.variances(model.drive, pieces)
    Qa = np.einsum("pik,pk,pjk->pij", J, var, J)
    c, sn = np.cos(inc[:, 2]), np.sin(inc[:, 2])
    T = np.zeros((len(pieces), 3, 3))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1], T[:, 2, 2] = c, sn, -sn, c, 1.0
    Q = T @ Qa @ np.swapaxes(T, 1, 2)
    TJD = None if D is None else T @ J @ D
    # Adjoint of inc^-1 (GTSAM Pose2::AdjointMap of the inverse): [[R^T, R^T [-y; x]], [0, 1]]
    x, y = inc[:, 0], inc[:, 1]
    A = np.zeros((len(pieces), 3, 3))
    A[:, :2, :2] = T[:, :2, :2]
    A[:, 0, 2] = c * (-y) + sn * x
    A[:, 1, 2] = -sn * (-y) + c * x
    A[:, 2, 2] = 1.0
    start = np.searchsorted(owner, np.arange(n_intervals), side="left")
    count = np.searchsorted(owner, np.arange(n_intervals), side="right") - start
    for j in range(int(count.max())):
        live = np.flatnonzero(count > j)
        idx = start[live] + j
        deltas[live] = se2.compose(deltas[live], inc[idx])
        Ai = A[idx]
        covs[live] = Ai @ covs[live] @ np.swapaxes(Ai, 1, 2) + Q[idx]
        if G is not None:
            G[live] = Ai @ G[live] + TJD[idx]
    covs = 0.5 * (covs + np.swapaxes(covs, 1, 2))
    return (deltas, covs) if G is None else (deltas, covs, G)


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

    ``value`` is ``false`` (none), ``true`` (default prior sigmas) or a list of prior sigmas.
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
        if not isinstance(value, list) or len(value) != len(names):
            raise ConfigError(
                f"expected true or {len(names)} prior sigmas for {', '.join(names)}",
                file=source,
                key=key,
            )
        sigma = tuple(_nonneg_option(v, f"{key}[{i}]", source) for i, v in enumerate(value))
        if min(sigma) <= 0:
            raise ConfigError("prior sigmas must be positive", file=source, key=key)
    return OdometryCalibration(names, nominal, tuple(sigma), name)


def _odometry_noise(cov, floor: float = _COV_FLOOR):
    import gtsam

    cov = 0.5 * (cov + cov.T)
    cov[0, 0] += floor
    cov[1, 1] += floor
    cov[2, 2] += floor
    return gtsam.noiseModel.Gaussian.Covariance(cov)


# --------------------------------------------------------------------------- problem
@dataclass
class _Measurement:
    stream: str
    index: int  # row in the stream
    keyframe: int  # keyframe index (the previous one too for the gyro: prev_keyframe)
    row: dict
    prev_keyframe: int | None = None
    landmark: int | None = None


@dataclass
class GraphProblem:
    """Everything the three solvers share (built once per run by :func:`build_problem`).

    Attributes
    ----------
    kt : ndarray (K,)
        Keyframe times (s).
    deltas, covs : ndarray (K-1, 3), (K-1, 3, 3)
        Pre-integrated odometry (body frame, GTSAM tangent covariance).
    pose0, P0 : ndarray (3,), (3, 3)
        Initial pose and its world-frame covariance.
    models : dict
        Stream -> measurement model.
    measurements : list
        Sensor rows with their keyframe, in time order.
    calib : dict
        Calibration state name -> (key, initial value, sigma).
    landmarks : dict
        Landmark id -> (2,) position: the map, or the SLAM initial guess.
    rejected : dict
        Stream -> rows that got no factor (outside the odometry span, unknown landmark, ...).
    """

    kt: np.ndarray
    deltas: np.ndarray
    covs: np.ndarray
    pose0: np.ndarray
    P0: np.ndarray
    models: dict
    measurements: list
    calib: dict
    landmarks: dict
    options: GraphOptions
    odometry_stream: str
    odometry_rows: int
    rejected: dict
    robust: dict
    odometry_calibration: OdometryCalibration | None = None
    G: np.ndarray | None = None

    @property
    def odometry_key(self) -> int:
        """Key of the odometry calibration vector (``o0``)."""
        import gtsam

        return gtsam.symbol("o", 0)

    def dead_reckoning(self) -> np.ndarray:
        """Keyframe poses ``(K, 3)`` obtained by composing the odometry factors from ``pose0``."""
        # pose_{i+1} = pose_i (+) d_i: theta by a running sum, positions by summing the
        # increments rotated into the world (head-to-tail composition, 002 source)
        theta = self.pose0[2] + np.concatenate([[0.0], np.cumsum(self.deltas[:, 2])])
        c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
        dx, dy = self.deltas[:, 0], self.deltas[:, 1]
        step = np.column_stack([c * dx - s * dy, s * dx + c * dy])
        xy = self.pose0[:2] + np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])
        return np.column_stack([xy, se2.wrap(theta)])


def _model_kind(model) -> str:
    return type(model).__name__


def build_problem(log, config, estimator: str) -> GraphProblem:
    """Keyframes, pre-integrated odometry and the sensor rows of a run (no GTSAM objects).

    Raises
    ------
    ConfigError, InputError
        Bad options (naming the key and file) or an unusable log.
    """
    from odofuse.measurements import measurement_models
    from odofuse.motion import motion_model_from_config

    options = parse_options(config, estimator)
    if options.slam and estimator != "smoother":
        raise ConfigError(
            "slam (unknown landmarks) is implemented for the batch smoother only",
            file=config.source,
            key=f"options.{estimator}.slam",
        )
    model = motion_model_from_config(config)
    t_odo, U = odometry_inputs(log, model)
    pose0, P0 = initial_state(config, log)
    models = measurement_models(config, _log_with_ids(log) if options.slam else log)
    t_lo, t_hi = float(t_odo[0]), float(t_odo[-1])

    rejected: dict[str, int] = {}
    pending: list[tuple[float, _Measurement]] = []
    for name, m in models.items():
        if not log.has(name):
            continue
        stream = log.streams[name]
        order = np.argsort(stream.t, kind="stable")  # a few logs (Plaza) are not sorted
        kind = _model_kind(m)
        prev_t = None
        n_rej = 0
        for i in order:
            t = float(stream.t[i])
            if not (t_lo <= t <= t_hi):
                n_rej += 1
                continue
            row = stream.row(int(i))
            if not all(math.isfinite(v) for v in row.values()):
                n_rej += 1
                continue
            meas = _Measurement(name, int(i), -1, row)
            if kind == "GyroYawRate":
                if prev_t is None or t <= prev_t:
                    prev_t = t if prev_t is None else prev_t
                    n_rej += 1
                    continue
                row["dt"] = t - prev_t
                meas.prev_keyframe = -1
                meas.row["t_prev"] = prev_t
                prev_t = t
            if kind in LANDMARK_SENSORS:
                lid = int(row["id"])
                if not options.slam and lid not in log.landmarks:
                    n_rej += 1
                    continue
                meas.landmark = lid
            pending.append((t, meas))
        rejected[name] = n_rej

    sensor_times = np.array([t for t, _ in pending])
    kt = keyframe_times(t_odo, U, model, sensor_times, options)
    for t, meas in pending:
        meas.keyframe = int(np.searchsorted(kt, t))
        if meas.prev_keyframe is not None:
            meas.prev_keyframe = int(np.searchsorted(kt, meas.row["t_prev"]))
    pending.sort(key=lambda tm: (tm[1].keyframe, tm[1].stream))
    odo_cal = odometry_calibration_for(
        model,
        options.odometry_calibration,
        f"options.{estimator}.odometry_calibration",
        config.source,
    )
    G = None
    if odo_cal is None:
        deltas, covs = preintegrate(t_odo, U, model, kt)
    else:
        deltas, covs, G = preintegrate(t_odo, U, model, kt, odo_cal)

    calib: dict[str, tuple[int, float, float]] = {}
    for m in models.values():
        clones = set(getattr(m, "clones", lambda: {})())
        prior = getattr(m, "calib_prior", lambda: {})()
        for state in getattr(m, "calib_states", ()):
            if state in clones or state in calib:
                continue
            value, sigma = prior.get(state, (0.0, 1.0))
            calib[state] = (_C(len(calib)), float(value), float(sigma))

    robust = {s: options.robust.get(s, ("none", 0.0)) for s in models}
    robust[odometry_stream_name(model)] = options.robust.get(
        odometry_stream_name(model), ("none", 0.0)
    )
    problem = GraphProblem(
        kt,
        deltas,
        covs,
        pose0,
        P0,
        models,
        [m for _, m in pending],
        calib,
        {int(i): np.asarray(p, dtype=float) for i, p in log.landmarks.items()},
        options,
        odometry_stream_name(model),
        len(U),
        rejected,
        robust,
        odo_cal,
        G,
    )
    if options.slam:
        problem.landmarks = slam_initial_landmarks(problem, problem.dead_reckoning())
    return problem


def _log_with_ids(log):
    """A view of ``log`` whose map lists every landmark id seen (positions unused in SLAM)."""
    import dataclasses

    ids = set(log.landmarks)
    for stream in log.streams.values():
        if "id" in stream.columns:
            ids.update(int(i) for i in np.unique(stream["id"]) if np.isfinite(i))
    return dataclasses.replace(log, landmarks={i: np.zeros(2) for i in ids})


def slam_initial_landmarks(problem: GraphProblem, poses) -> dict[int, np.ndarray]:
    """Robust initial positions of unknown landmarks from ranges and a pose guess.

    For every landmark id with range rows (range or range-bearing sensors) a grid of cell
    ``slam_grid`` m over the poses' bounding box grown by the largest range is scored with a
    truncated quadratic of ``||p_k - l|| - r_k`` (truncated at 3 sigma, so multipath outliers
    and a few-percent scale error cannot pull the minimum), then refined by Gauss-Newton on the
    inliers. The range-only ring ambiguity is broken by the robot's own motion: a landmark seen
    from a 2-D path has one minimum. Bearings, when present, go through the same cost.

    Returns
    -------
    dict
        id -> ``(2,)`` world position (m).
    """
    poses = np.asarray(poses, dtype=float)
    per_id: dict[int, list[tuple[np.ndarray, float, float]]] = {}
    for meas in problem.measurements:
        if meas.landmark is None:
            continue
        m = problem.models[meas.stream]
        kind = _model_kind(m)
        if kind == "BeaconRange":
            r, sigma = float(meas.row["range"]), float(m.sigma)
        elif kind == "LandmarkRangeBearing":
            r, sigma = float(meas.row["range"]), float(m.sigma)
        else:
            continue
        per_id.setdefault(meas.landmark, []).append((poses[meas.keyframe, :2], r, sigma))
    out: dict[int, np.ndarray] = {}
    cell = problem.options.slam_grid
    for lid, obs in sorted(per_id.items()):
        P = np.array([o[0] for o in obs])
        R = np.array([o[1] for o in obs])
        sig = np.array([o[2] for o in obs])
        if len(obs) > 400:  # a spread-out subsample is plenty for the grid
            pick = np.linspace(0, len(obs) - 1, 400).astype(int)
            Pg, Rg, Sg = P[pick], R[pick], sig[pick]
        else:
            Pg, Rg, Sg = P, R, sig
        lo = P.min(0) - R.max()
        hi = P.max(0) + R.max()
        gx = np.arange(lo[0], hi[0] + cell, cell)
        gy = np.arange(lo[1], hi[1] + cell, cell)
        G = np.stack(np.meshgrid(gx, gy, indexing="ij"), -1).reshape(-1, 2)
        best, best_cost = None, np.inf
        for chunk in np.array_split(np.arange(len(G)), max(1, len(G) // 4000)):
            d = np.linalg.norm(G[chunk, None, :] - Pg[None], axis=2)
            e = np.minimum(((d - Rg) / Sg) ** 2, 9.0)
            cost = e.sum(1)
            j = int(np.argmin(cost))
            if cost[j] < best_cost:
                best, best_cost = G[chunk][j].copy(), float(cost[j])
        lm = best
        for _ in range(20):  # Gauss-Newton on the 3-sigma inliers
            diff = lm - P
            d = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
            e = (d - R) / sig
            inl = np.abs(e) < 3.0
            if inl.sum() < 3:
                break
            J = diff[inl] / d[inl, None] / sig[inl, None]
            step = np.linalg.lstsq(J, -e[inl], rcond=None)[0]
            lm = lm + step
            if np.linalg.norm(step) < 1e-6:
                break
        out[lid] = lm
    return out


# --------------------------------------------------------------------------- factors
class _Factors:
    """Turns a :class:`GraphProblem` into GTSAM factors and initial values, keyframe by keyframe."""

    def __init__(self, problem: GraphProblem) -> None:
        import gtsam

        self.p = problem
        self.gtsam = gtsam
        self.dims: dict[int, int] = {}
        self.python_factors = 0
        self.used: dict[str, int] = {problem.odometry_stream: problem.odometry_rows}
        for s in problem.models:
            self.used.setdefault(s, 0)
        self.created: list = []  # (measurement, factor) in the order added
        self.by_kf: dict[int, list[_Measurement]] = {}
        for meas in problem.measurements:
            self.by_kf.setdefault(meas.keyframe, []).append(meas)
        self.landmark_keys: dict[int, int] = {}
        needs_landmarks = {m.landmark for m in problem.measurements if m.landmark is not None}
        for lid in sorted(needs_landmarks):
            if self._landmark_variable_needed(lid):
                self.landmark_keys[lid] = _L(lid)
        self.calib_keys = {name: key for name, (key, _, _) in problem.calib.items()}
        # calibration state -> constant used by new factors once frozen (iSAM2 only)
        self.frozen: dict[str, float] = {}
        # frozen beacon ranges: (factor, private beacon key, beacon position) to add with
        # the next keyframe, and the factor -> range scale its unwhitened error is divided by
        self._pending: list = []
        self.error_scale: dict[int, float] = {}

    def _landmark_variable_needed(self, lid) -> bool:
        if self.p.options.slam:
            return True
        # Known landmarks become pinned variables only for factors without calibration keys.
        return any(
            m.landmark == lid and not self._model_calib(self.p.models[m.stream])
            for m in self.p.measurements
        )

    def _model_calib(self, model) -> dict:
        clones = set(getattr(model, "clones", lambda: {})())
        return {
            s: self.p.calib[s][0]
            for s in getattr(model, "calib_states", ())
            if s in self.p.calib and s not in clones
        }

    def static(self):
        """Priors on the first pose, calibration states and landmarks, with their values."""
        gtsam = self.gtsam
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        p = self.p
        pose0 = gtsam.Pose2(*p.pose0)
        g.add(
            gtsam.PriorFactorPose2(
                _X(0),
                pose0,
                gtsam.noiseModel.Gaussian.Covariance(se2.cov_world_to_body(p.pose0, p.P0)),
            )
        )
        v.insert(_X(0), pose0)
        self.dims[_X(0)] = 3
        for _name, (key, value, sigma) in p.calib.items():
            v.insert(key, np.array([value]))
            g.add(
                gtsam.PriorFactorVector(
                    key, np.array([value]), gtsam.noiseModel.Isotropic.Sigma(1, sigma)
                )
            )
            self.dims[key] = 1
        if p.odometry_calibration is not None:
            oc = p.odometry_calibration
            v.insert(p.odometry_key, np.array(oc.nominal))
            prior = gtsam.noiseModel.Diagonal.Sigmas(np.array(oc.sigma))
            g.add(gtsam.PriorFactorVector(p.odometry_key, np.array(oc.nominal), prior))
            self.dims[p.odometry_key] = len(oc.nominal)
        for lid, key in self.landmark_keys.items():
            pos = p.landmarks.get(lid)
            v.insert(key, gtsam.Point2(*pos))
            self.dims[key] = 2
            if not p.options.slam:
                g.add(
                    gtsam.PriorFactorPoint2(
                        key,
                        gtsam.Point2(*pos),
                        gtsam.noiseModel.Isotropic.Sigma(2, p.options.known_landmark_sigma),
                    )
                )
        return g, v

    def odometry(self, i: int):
        """``BetweenFactorPose2`` from keyframe ``i-1`` to ``i``."""
        d = self.p.deltas[i - 1]
        loss, k = self.p.robust.get(self.p.odometry_stream, ("none", 0.0))
        nm = robust_noise(
            _odometry_noise(self.p.covs[i - 1], self.p.options.odometry_floor), loss, k
        )
        oc = self.p.odometry_calibration
        if oc is not None:
            self.python_factors += 1
            return calibrated_between_factor(
                _X(i - 1), _X(i), self.p.odometry_key, d, self.p.G[i - 1], oc.nominal, nm
            )
        return self.gtsam.BetweenFactorPose2(_X(i - 1), _X(i), self.gtsam.Pose2(*d), nm)

    def measurement(self, meas: _Measurement):
        """The factor of one sensor row (robust loss of its stream applied)."""
        gtsam = self.gtsam
        m = self.p.models[meas.stream]
        kind = _model_kind(m)
        calib = self._model_calib(m)
        loss, k = self.p.robust.get(meas.stream, ("none", 0.0))
        key = _X(meas.keyframe)
        if kind == "GyroYawRate":
            dt = float(meas.row["dt"])
            base = gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(m.R(meas.row)[0, 0]) * dt)
            f = m.factor(
                (_X(meas.prev_keyframe), key), meas.row, calib, robust_noise(base, loss, k)
            )
            self.python_factors += 1
            return f
        if kind == "LandmarkRangeBearing" and meas.landmark in self.landmark_keys:
            # GTSAM's BearingRange measurement is ordered (bearing, range).
            R = m.R(meas.row)
            base = gtsam.noiseModel.Diagonal.Sigmas(np.sqrt([R[1, 1], R[0, 0]]))
            return m.factor(
                key,
                meas.row,
                None,
                robust_noise(base, loss, k),
                landmark_key=self.landmark_keys[meas.landmark],
            )
        base = m.noise(meas.row)
        nm = robust_noise(base, loss, k)
        if kind == "BeaconRange" and meas.landmark in self.landmark_keys:
            lkey = self.landmark_keys[meas.landmark]
            if calib:
                self.python_factors += 1
                return range_landmark_factor(
                    key,
                    lkey,
                    meas.row["range"],
                    nm,
                    calib.get("range_scale"),
                    calib.get("range_offset"),
                )
            return gtsam.RangeFactor2D(key, lkey, float(meas.row["range"]), nm)
        if kind == "LandmarkBearing" and meas.landmark in self.landmark_keys:
            return m.factor(key, meas.row, None, nm, landmark_key=self.landmark_keys[meas.landmark])
        if calib and all(s in self.frozen for s in calib) and kind == "BeaconRange":
            return self._frozen_beacon_range(m, meas, loss, k)
        if calib and all(s in self.frozen for s in calib):
            self.python_factors += 1
            consts = {s: self.frozen[s] for s in calib}
            return frozen_calibration_factor(m, key, meas.row, consts, nm)
        f = m.factor(key, meas.row, calib, nm)
        if isinstance(f, gtsam.CustomFactor):
            self.python_factors += 1
        return f

    def _frozen_beacon_range(self, m, meas, loss, k):
        """A frozen ``s ||p - b|| + o = z`` range as built-in GTSAM factors.

        ``(s d + o - z) / sigma = (d - z') / sigma'`` with ``z' = (z - o) / s`` and
        ``sigma' = sigma / s``: the same whitened error (and robust weight, whose threshold
        is in sigma), so ``RangeFactor2D(x, b_n, z', sigma')`` to a *private* copy ``b_n``
        of the beacon, pinned by a ``known_landmark_sigma`` prior, is the calibrated factor
        with constant ``s, o``. A private copy per factor keeps the factor local (a shared
        beacon variable would tie all range factors together again) and built-in (a Python
        ``CustomFactor`` linearised inside iSAM2 costs a copy of all the values).
        """
        gtsam = self.gtsam
        scale = self.frozen.get("range_scale", 1.0)
        offset = self.frozen.get("range_offset", 0.0)
        sigma = math.sqrt(float(m.R(meas.row)[0, 0])) / scale
        nm = robust_noise(gtsam.noiseModel.Isotropic.Sigma(1, sigma), loss, k)
        z = (float(meas.row["range"]) - offset) / scale
        bkey = _B(len(self.error_scale))
        f = gtsam.RangeFactor2D(_X(meas.keyframe), bkey, z, nm)
        pos = np.asarray(self.p.landmarks[meas.landmark], dtype=float)
        self._pending.append((bkey, gtsam.Point2(*pos)))
        self.error_scale[id(f)] = 1.0 / scale
        self.dims[bkey] = 2
        return f

    def keyframe(self, i: int, values_guess, g=None, v=None):
        """Factors and new values of keyframe ``i`` (odometry from ``i-1`` and its sensors),
        added to ``g``/``v`` (new containers when omitted)."""
        gtsam = self.gtsam
        if g is None:
            g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if i > 0:
            g.add(self.odometry(i))
            v.insert(_X(i), values_guess)
            self.dims[_X(i)] = 3
        for meas in self.by_kf.get(i, ()):
            f = self.measurement(meas)
            g.add(f)
            self.created.append((meas, f))
            self.used[meas.stream] = self.used.get(meas.stream, 0) + 1
        pin = gtsam.noiseModel.Isotropic.Sigma(2, self.p.options.known_landmark_sigma)
        for bkey, pos in self._pending:
            v.insert(bkey, pos)
            g.add(gtsam.PriorFactorPoint2(bkey, pos, pin))
        self._pending.clear()
        return g, v


# --------------------------------------------------------------------------- results
def _pose_array(values, K) -> np.ndarray:
    out = np.empty((K, 3))
    for i in range(K):
        p = values.atPose2(_X(i))
        out[i] = (p.x(), p.y(), p.theta())
    out[:, 2] = se2.wrap(out[:, 2])
    return out


def _extra(problem: GraphProblem, fac: _Factors, values, estimator: str) -> dict:
    extra: dict = {"keyframes": int(len(problem.kt)), "python_factors": fac.python_factors}
    cal = {}
    for name, (key, _, _) in problem.calib.items():
        if values.exists(key):
            cal[name] = float(values.atVector(key)[0])
    oc = problem.odometry_calibration
    if oc is not None and values.exists(problem.odometry_key):
        vec = values.atVector(problem.odometry_key)
        cal.update({n: float(x) for n, x in zip(oc.names, vec, strict=True)})
    if cal:
        extra["calibration"] = cal
    if problem.options.slam:
        extra["landmarks"] = {
            int(lid): [float(c) for c in values.atPoint2(key)]
            for lid, key in fac.landmark_keys.items()
            if values.exists(key)
        }
    return extra


def _outliers(problem: GraphProblem, fac: _Factors, values) -> dict[str, int]:
    """Per stream: factors whose whitened residual exceeds the model's chi-square gate."""
    from odofuse.measurements import gate_threshold

    out: dict[str, int] = {}
    thresholds: dict[tuple, float] = {}
    for meas, f in fac.created:
        m = problem.models[meas.stream]
        if getattr(m, "gate", None) is None:
            continue
        e = np.atleast_1d(f.unwhitenedError(values)) / fac.error_scale.get(id(f), 1.0)
        R = m.R(meas.row)
        kind = _model_kind(m)
        if kind == "GyroYawRate":  # the factor's error is a heading change (rad), R a rate
            e = e / float(meas.row["dt"])
        elif e.size == 2 and kind == "LandmarkRangeBearing":  # GTSAM: (bearing, range)
            e = e[::-1]
        nis = float(e[0] * e[0] / R[0, 0]) if e.size == 1 else float(e @ np.linalg.solve(R, e))
        key = (m.gate, e.size)
        if key not in thresholds:
            thresholds[key] = gate_threshold(m.gate, e.size)
        if nis > thresholds[key]:
            out[meas.stream] = out.get(meas.stream, 0) + 1
    return out


def _world_covs(problem, poses, cov_of) -> np.ndarray:
    covs = np.empty((len(poses), 3, 3))
    for i in range(len(poses)):
        covs[i] = se2.cov_body_to_world(poses[i], cov_of(_X(i)))
    return 0.5 * (covs + np.swapaxes(covs, 1, 2))


def _finish(problem, fac, values, covs, estimator, extra) -> EstimateResult:
    poses = _pose_array(values, len(problem.kt))
    extra = {**_extra(problem, fac, values, estimator), **extra}
    outliers = _outliers(problem, fac, values)
    if outliers:
        extra["outliers"] = outliers
    traj = Trajectory(problem.kt.copy(), poses, covs)
    used = {k: int(v) for k, v in fac.used.items()}
    return EstimateResult(estimator, traj, used, dict(problem.rejected), extra)


# --------------------------------------------------------------------------- solvers
def build_graph(problem: GraphProblem):
    """The whole graph and its dead-reckoned / SLAM-initialised values (batch form)."""
    fac = _Factors(problem)
    graph, values = fac.static()
    guess = problem.dead_reckoning()
    import gtsam

    for i in range(len(problem.kt)):
        fac.keyframe(i, gtsam.Pose2(*guess[i]), graph, values)
    return fac, graph, values


def run_smoother(log, config) -> EstimateResult:
    """Batch Levenberg-Marquardt over the whole log (``estimator: smoother``).

    Returns
    -------
    EstimateResult
        Keyframe poses with world-frame marginal covariances; ``used``/``rejected`` per
        stream; ``extra``: ``calibration`` (state -> value), ``landmarks`` (SLAM: id -> [x, y]),
        ``outliers`` (per stream, beyond the model's gate at the optimum), ``keyframes``,
        ``iterations``, ``final_error``, ``solve_s``.
    """
    import gtsam

    problem = build_problem(log, config, "smoother")
    fac, graph, values = build_graph(problem)
    opts = problem.options
    t0 = time.perf_counter()
    if fac.python_factors:
        result, iterations, err = levenberg_marquardt(
            graph, values, fac.dims, opts.max_iterations, opts.relative_tolerance
        )
    else:
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(opts.max_iterations)
        params.setRelativeErrorTol(opts.relative_tolerance)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        result = optimizer.optimize()
        iterations, err = optimizer.iterations(), graph.error(result)
    solve_s = time.perf_counter() - t0
    covs = None
    if opts.covariances:
        marginals = gtsam.Marginals(graph, result)
        poses = _pose_array(result, len(problem.kt))
        covs = _world_covs(problem, poses, marginals.marginalCovariance)
        if problem.calib:
            sig = {
                name: float(np.sqrt(marginals.marginalCovariance(key)[0, 0]))
                for name, (key, _, _) in problem.calib.items()
            }
    extra = {"iterations": int(iterations), "final_error": float(err), "solve_s": solve_s}
    if opts.covariances and problem.calib:
        extra["calibration_sigma"] = sig
    return _finish(problem, fac, result, covs, "smoother", extra)


def _latency_summary(lat) -> dict:
    lat = np.asarray(lat) * 1e3
    if lat.size == 0:
        return {}
    quarters = np.array_split(lat, 4) if lat.size >= 4 else [lat]
    return {
        "median_ms": float(np.median(lat)),
        "p99_ms": float(np.percentile(lat, 99)),
        "max_ms": float(lat.max()),
        "updates": int(lat.size),
        # how latency grows with the log: median and p99 of each quarter of the updates
        "quarters_median_ms": [float(np.median(q)) for q in quarters],
        "quarters_p99_ms": [float(np.percentile(q, 99)) for q in quarters],
    }


def _isam2_params(options: GraphOptions):
    """iSAM2 parameters. Relinearisation is kept coarse (0.1 m / rad every 10 updates by
    default) because a calibration variable touches every range factor: relinearising it
    re-runs all their Python callbacks."""
    import gtsam

    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(options.relinearize_threshold)
    params.relinearizeSkip = options.relinearize_skip
    # QR: pinned landmarks (sigma 1e-6 m) and 0.1 mm odometry floors make the normal
    # equations too ill-conditioned for iSAM2's Cholesky.
    params.setFactorization("QR")
    return params


def _freeze_groups(problem: GraphProblem, fac: _Factors, source: str) -> dict[str, tuple[str, ...]]:
    """Stream -> calibration states that ``calibration_freeze`` freezes together.

    A sensor's later factors can use constants only when *all* its calibration states are
    frozen, so each stream with calibration states forms one group. Only unary sensor
    factors can be frozen (the gyro's heading-increment factor is not). With absolute
    thresholds every group must have a threshold for each of its states and naming a gyro
    state is an error; with the convergence form every freezable sensor forms a group and a
    gyro's states simply stay estimated.
    """
    spec = problem.options.calibration_freeze
    if not spec:
        return {}
    if "rel_change" in spec:
        return {
            stream: tuple(fac._model_calib(m))
            for stream, m in problem.models.items()
            if fac._model_calib(m) and _model_kind(m) != "GyroYawRate"
        }
    key = "options.isam2.calibration_freeze.sigma"
    known = set(problem.calib)
    bad = sorted(set(spec["sigma"]) - known)
    if bad:
        raise ConfigError(
            f"'{bad[0]}' is not an estimated calibration state "
            f"(estimated: {', '.join(sorted(known)) or 'none'})",
            source,
            f"{key}.{bad[0]}",
        )
    groups: dict[str, tuple[str, ...]] = {}
    for stream, m in problem.models.items():
        states = tuple(fac._model_calib(m))
        if not states or not set(states) & set(spec["sigma"]):
            continue
        if _model_kind(m) == "GyroYawRate":
            raise ConfigError(
                "the gyro's heading-increment factor cannot be frozen (unary sensors only)",
                source,
                f"{key}.{next(s for s in states if s in spec['sigma'])}",
            )
        missing = [s for s in states if s not in spec["sigma"]]
        if missing:
            raise ConfigError(
                f"sensor '{stream}' estimates {', '.join(states)}: give a threshold for each",
                source,
                f"{key}.{missing[0]}",
            )
        groups[stream] = states
    return groups


def _converged(history: list, t: float, n: int, sig: dict, spec: dict) -> tuple[bool, dict]:
    """The convergence test of ``calibration_freeze: {rel_change, window}`` for one sensor.

    Parameters
    ----------
    history : list of (t [s], n factors, {state: sigma})
        Earlier checks of this sensor, in time order.
    t : float
        s, log time of this check; ``n`` the sensor's factor count so far; ``sig`` the
        current marginal sigma of each of its calibration states.
    spec : dict
        The parsed option (``rel_change``, ``window`` [s]).

    Returns
    -------
    (bool, dict)
        Whether every sigma shrank by less than ``rel_change`` (relative) since the last check
        at least ``window`` s ago, with at least one new factor of the sensor since then; and
        the sigmas of that earlier check (empty if there is none yet).
    """
    times = [h[0] for h in history]
    j = bisect.bisect_right(times, t - spec["window"]) - 1
    if j < 0:
        return False, {}
    _, n_then, sig_then = history[j]
    if n <= n_then:  # no new measurement: no evidence that the information stopped growing
        return False, sig_then
    ok = all(sig_then[s] - sig[s] < spec["rel_change"] * sig_then[s] for s in sig)
    return ok, sig_then


def run_isam2(log, config) -> EstimateResult:
    """iSAM2, one update per keyframe in time order (``estimator: isam2``).

    The trajectory is the final iSAM2 estimate (after ``final_relinearizations`` forced
    relinearising updates); ``extra["latency"]`` summarises the wall time of each
    ``ISAM2.update`` and ``extra["latency_step"]`` that of the whole per-keyframe step
    (factor creation, update, freeze check, current-pose estimate), median / p99 / max and per
    quarter of the log, ms.

    Calibration freezing (``options.isam2.calibration_freeze``): a calibration variable
    (e.g. range scale/offset) is connected to every factor of its sensor, so each update
    touches it and iSAM2's cost grows with the number of those factors. Every
    ``check_every`` updates the marginal sigma of each calibration state is read from the
    Bayes tree; once all the states of a sensor are below their thresholds (``sigma`` form)
    or have converged (``rel_change`` form: each sigma shrank by less than ``rel_change``
    over the last ``window`` s of log time, the sensor got new factors in that window and
    ``min_time`` s have elapsed), that sensor's later factors hold the current estimate as constants
    (:func:`graph_factors.frozen_calibration_factor`) and no longer involve the variable. The
    variable stays in the graph, still estimated from the factors added before the freeze;
    what is given up is the information of the later measurements about the calibration
    (and its correlation with the later poses). ``extra["calibration_freeze"]`` gives, per
    frozen state, the constant, its sigma, the keyframe index and time of the freeze (and,
    for the ``rel_change`` form, ``sigma_window_ago``: its sigma one window earlier).
    """
    import gtsam

    problem = build_problem(log, config, "isam2")
    fac = _Factors(problem)
    groups = _freeze_groups(problem, fac, getattr(config, "source", "<config>"))
    spec = problem.options.calibration_freeze or {}
    params = _isam2_params(problem.options)
    isam = gtsam.ISAM2(params)
    graph, values = fac.static()
    # Calibration states touch every factor of their sensor: relinearising them online would
    # re-run all those (Python) factors, so they are relinearised only in the final passes
    # (range and gyro models are linear in them anyway).
    frozen = gtsam.KeyList()
    for key, _, _ in problem.calib.values():
        frozen.push_back(key)
    if problem.odometry_calibration is not None:
        frozen.push_back(problem.odometry_key)
    latency, step = [], []
    freeze_info: dict[str, dict] = {}
    frozen_streams: set[str] = set()
    history: dict[str, list] = {stream: [] for stream in groups}
    n_factors: dict[str, int] = {}
    current = gtsam.Pose2(*problem.pose0)
    for i in range(len(problem.kt)):
        t_step = time.perf_counter()
        if i > 0:
            current = current.compose(gtsam.Pose2(*problem.deltas[i - 1]))
        g, v = fac.keyframe(i, current)
        graph.push_back(g)
        values.insert(v)
        t0 = time.perf_counter()
        isam.update(graph, values, noRelinKeys=frozen)
        latency.append(time.perf_counter() - t0)
        for meas in fac.by_kf.get(i, ()):
            n_factors[meas.stream] = n_factors.get(meas.stream, 0) + 1
        if groups and i % spec["check_every"] == 0:
            t_i = float(problem.kt[i])
            for stream in [s for s in groups if s not in frozen_streams]:
                sig = {
                    s: float(np.sqrt(isam.marginalCovariance(problem.calib[s][0])[0, 0]))
                    for s in groups[stream]
                }
                before: dict = {}
                if "sigma" in spec:
                    ok = all(sig[s] < spec["sigma"][s] for s in groups[stream])
                else:
                    n = n_factors.get(stream, 0)
                    ok, before = _converged(history[stream], t_i, n, sig, spec)
                    ok = ok and t_i - float(problem.kt[0]) >= spec["min_time"]
                    history[stream].append((t_i, n, sig))
                if ok:
                    for s in groups[stream]:
                        value = float(isam.calculateEstimateVector(problem.calib[s][0])[0])
                        fac.frozen[s] = value
                        freeze_info[s] = {
                            "value": value,
                            "sigma": sig[s],
                            "keyframe": i,
                            "t": t_i,
                        }
                        if before:
                            freeze_info[s]["sigma_window_ago"] = before[s]
                    frozen_streams.add(stream)
        if i > 0:
            current = isam.calculateEstimatePose2(_X(i))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        step.append(time.perf_counter() - t_step)
    for _ in range(problem.options.final_relinearizations):
        isam.update(force_relinearize=True)
    result = isam.calculateEstimate()
    covs = None
    if problem.options.covariances:
        poses = _pose_array(result, len(problem.kt))
        covs = _world_covs(problem, poses, isam.marginalCovariance)
    extra = {"latency": _latency_summary(latency), "latency_step": _latency_summary(step)}
    if groups:
        extra["calibration_freeze"] = freeze_info
    return _finish(problem, fac, result, covs, "isam2", extra)


def run_fixed_lag(log, config) -> EstimateResult:
    """GTSAM ``IncrementalFixedLagSmoother`` with a ``lag``-second window (``fixed_lag``).

    Each keyframe's pose (and world-frame covariance) is the one held just before it leaves
    the window, i.e. smoothed with ``lag`` seconds of future data; memory is bounded by the
    window. Calibration and landmark variables are kept in the window.
    """
    import gtsam

    problem = build_problem(log, config, "fixed_lag")
    fac = _Factors(problem)
    lag = problem.options.lag
    params = _isam2_params(problem.options)
    smoother = gtsam.IncrementalFixedLagSmoother(lag, params)
    graph, values = fac.static()
    persistent = [k for k in values.keys() if k != _X(0)]
    K = len(problem.kt)
    poses = np.empty((K, 3))
    covs = np.empty((K, 3, 3)) if problem.options.covariances else None
    done = 0  # keyframes [0, done) are final
    latency = []
    final_values = gtsam.Values()
    current = gtsam.Pose2(*problem.pose0)

    def freeze(upto: int) -> None:
        nonlocal done
        while done < upto:
            p = smoother.calculateEstimatePose2(_X(done))
            poses[done] = (p.x(), p.y(), p.theta())
            if covs is not None:
                covs[done] = se2.cov_body_to_world(
                    poses[done], smoother.marginalCovariance(_X(done))
                )
            done += 1

    for i in range(K):
        t = float(problem.kt[i])
        if i > 0:
            current = current.compose(gtsam.Pose2(*problem.deltas[i - 1]))
        # keyframes that this update will marginalise: take their final estimate first
        freeze(int(np.searchsorted(problem.kt, t - lag, side="left")) if i > 0 else 0)
        g, v = fac.keyframe(i, current)
        graph.push_back(g)
        values.insert(v)
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        stamps.insert((_X(i), t))
        for key in persistent:
            stamps.insert((key, t))
        t0 = time.perf_counter()
        smoother.update(graph, values, stamps)
        latency.append(time.perf_counter() - t0)
        current = smoother.calculateEstimatePose2(_X(i))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    freeze(K)
    poses[:, 2] = se2.wrap(poses[:, 2])
    est = smoother.calculateEstimate()
    for key in persistent:
        if est.exists(key):
            final_values.insert(
                key, est.atVector(key) if gtsam.Symbol(key).chr() == ord("c") else est.atPoint2(key)
            )
    for i in range(K):
        final_values.insert(_X(i), gtsam.Pose2(*poses[i]))
    extra = {"latency": _latency_summary(latency), "lag_s": lag}
    return _finish(problem, fac, final_values, covs, "fixed_lag", extra)
