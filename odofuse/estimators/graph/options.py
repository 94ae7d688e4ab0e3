"""Options of the graph estimators: :class:`GraphOptions` and :func:`parse_options`.

Owns the keys accepted in ``options.<smoother|isam2|fixed_lag>``, their defaults and their
validation into :class:`GraphOptions` (a one-line :class:`~odofuse.errors.ConfigError` naming
the key and the file), and the robust-loss names with their default thresholds. The options
are documented in ``docs/graph.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from odofuse.declarations import ROBUST_DEFAULT_K, ROBUST_KINDS  # noqa: F401 - re-exported
from odofuse.declarations import robust_loss as _robust_entry
from odofuse.errors import ConfigError

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
    "slam_init",
)
#: Values of ``slam_init`` (the smoother's initial values of a SLAM problem).
SLAM_INITS = ("auto", "incremental", "dead_reckoning")


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
    slam_init : str
        Smoother only: initial values of a SLAM problem. ``incremental``: an iSAM2 pass in
        which each landmark enters from the current estimate of the poses
        (:mod:`odofuse.estimators.graph.isam2_slam`); ``dead_reckoning``: dead-reckoned poses
        and landmarks placed off them; ``auto`` (default): ``incremental`` unless the graph
        estimates calibration states (their Python factors, relinearised inside iSAM2, make
        the pass slow).
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
    slam_init: str = "auto"


def nonneg_option(value, key, source) -> float:
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
            sigma[str(state)] = nonneg_option(v, f"{key}.sigma.{state}", source)
            if sigma[str(state)] == 0.0:
                raise ConfigError("must be positive", source, f"{key}.sigma.{state}")
        return {"sigma": sigma, "check_every": every}
    if "rel_change" not in value:
        raise ConfigError(f"expected {form}, got {value!r}", source, key)
    rel = nonneg_option(value["rel_change"], f"{key}.rel_change", source)
    if not 0.0 < rel < 1.0:
        raise ConfigError(
            f"must be a fraction in (0, 1), got {value['rel_change']!r}",
            source,
            f"{key}.rel_change",
        )
    if "window" not in value:
        raise ConfigError("required with rel_change (s of log time)", source, f"{key}.window")
    window = nonneg_option(value["window"], f"{key}.window", source)
    if window == 0.0:
        raise ConfigError("must be positive", source, f"{key}.window")
    min_time = nonneg_option(value.get("min_time", 0.0), f"{key}.min_time", source)
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
            kw[key] = nonneg_option(value, k, source)
        elif key in ("lag", "slam_grid", "known_landmark_sigma"):
            v = nonneg_option(value, k, source)
            if v == 0.0:
                raise ConfigError("must be positive", file=source, key=k)
            kw[key] = v
        elif key in ("keyframe_every_step", "slam", "covariances"):
            kw[key] = _bool_option(value, k, source)
        elif key in ("relinearize_threshold", "odometry_floor"):
            kw[key] = nonneg_option(value, k, source)
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
        elif key == "slam_init":
            if value not in SLAM_INITS:
                raise ConfigError(
                    f"expected one of {', '.join(SLAM_INITS)}, got {value!r}", source, k
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
