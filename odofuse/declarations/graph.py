"""Declarations of the graph estimators' block ``options.<smoother|isam2|fixed_lag>``.

Owns :class:`GraphOptions` (every key the smoother, iSAM2 and the fixed-lag smoother accept,
with type, unit, default and meaning), its parse hooks for the forms an annotation cannot say
(``robust``: one loss or stream -> loss; ``calibration_freeze``: absolute thresholds or a
convergence test) and :meth:`GraphOptions.for_run`, the checks and merge that need the rest of
the run config (the sensor blocks' own ``robust``, the estimator's name). The graph package
(:mod:`odofuse.estimators.graph`) receives the resolved instance from
:meth:`odofuse.config.RunConfig.estimator_options`.
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Mapping
from dataclasses import dataclass

from odofuse.declarations.common import _NONNEG, _POSITIVE, robust_loss
from odofuse.errors import ConfigError
from odofuse.options import explicit, option

#: Values of ``slam_init`` (the smoother's initial values of a SLAM problem).
SLAM_INITS = ("auto", "incremental", "dead_reckoning")
#: Streams a ``robust`` mapping may name besides the sensor blocks: the odometry stream.
ODOMETRY_STREAMS = ("odometry", "wheels")
#: Estimators whose block is a :class:`GraphOptions`.
GRAPH_ESTIMATORS = ("smoother", "isam2", "fixed_lag")

_LOSS = "huber \\| cauchy \\| tukey \\| none or {type, k}"


def robust_option(value, key: str, source: str):
    """``robust``: one loss for every sensor stream as ``(kind, k)``, or stream -> ``(kind, k)``.

    A mapping with a key other than ``type`` and ``k`` is read as stream -> loss; anything else
    (a loss name, ``{type, k}``, ``null`` = ``none``) is one loss.
    """
    if isinstance(value, Mapping) and (set(value) - {"type", "k"}):
        return types.MappingProxyType(
            {str(s): robust_loss(v, f"{key}.{s}", source) for s, v in value.items()}
        )
    return robust_loss(value, key, source)


def _positive_number(value, key: str, source: str) -> float:
    """A finite number ``> 0`` (``bool`` refused), for the ``calibration_freeze`` thresholds."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"expected a number, got {value!r}", file=source, key=key)
    v = float(value)
    if not (math.isfinite(v) and v >= 0.0):
        raise ConfigError(f"must be a non-negative number, got {value!r}", file=source, key=key)
    if v == 0.0:
        raise ConfigError("must be positive", file=source, key=key)
    return v


def freeze_option(value, key: str, source: str):
    """Validate ``calibration_freeze`` (isam2 only) into one of two read-only forms.

    Absolute thresholds: ``{sigma: {state: positive float}, check_every: n}``.
    Convergence: ``{rel_change: r, window: W, min_time: T, check_every: n}`` with
    ``0 < r < 1``, ``W > 0`` s of log time and ``T >= 0`` s (default 0). Exactly one of
    ``sigma`` and ``rel_change`` must be given; ``check_every`` defaults to 10.
    """
    form = "{sigma: {state: threshold}} or {rel_change: r, window: s}"
    if not isinstance(value, Mapping):
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
        if not isinstance(value["sigma"], Mapping):
            raise ConfigError(
                f"expected {{state: threshold}}, got {value['sigma']!r}", source, f"{key}.sigma"
            )
        sigma = {
            str(state): _positive_number(v, f"{key}.sigma.{state}", source)
            for state, v in value["sigma"].items()
        }
        return types.MappingProxyType(
            {"sigma": types.MappingProxyType(sigma), "check_every": every}
        )
    if "rel_change" not in value:
        raise ConfigError(f"expected {form}, got {value!r}", source, key)
    rel = value["rel_change"]
    if isinstance(rel, bool) or not isinstance(rel, int | float) or not 0.0 < rel < 1.0:
        raise ConfigError(f"must be a fraction in (0, 1), got {rel!r}", source, f"{key}.rel_change")
    if "window" not in value:
        raise ConfigError("required with rel_change (s of log time)", source, f"{key}.window")
    window = _positive_number(value["window"], f"{key}.window", source)
    min_time = value.get("min_time", 0.0)
    number = isinstance(min_time, int | float) and not isinstance(min_time, bool)
    if not (number and math.isfinite(min_time) and min_time >= 0):
        raise ConfigError(
            f"must be a non-negative number, got {min_time!r}", source, f"{key}.min_time"
        )
    return types.MappingProxyType(
        {
            "rel_change": float(rel),
            "window": window,
            "min_time": float(min_time),
            "check_every": every,
        }
    )


@dataclass(frozen=True)
class GraphOptions:
    """``options.<smoother|isam2|fixed_lag>``: the factor-graph estimators (docs/graph.md).

    The same keys for the three estimators (a key one of them does not use is ignored by it).
    As validated from the block, ``robust`` is what the block says (one loss for every sensor,
    or stream -> loss, or ``None`` when absent); :meth:`for_run` resolves it into the mapping
    stream -> ``(kind, k)`` the graph uses, merged with the sensor blocks' own ``robust``.
    """

    keyframe_dt: float = option(
        1.0, unit="s", doc="a keyframe at least this often (0: off)", **_NONNEG
    )
    keyframe_ds: float = option(
        0.0, unit="m", doc="odometry travel between keyframes (0: off)", **_NONNEG
    )
    keyframe_dtheta: float = option(
        0.0, unit="rad", doc="odometry rotation between keyframes (0: off)", **_NONNEG
    )
    keyframe_every_step: bool = option(
        False,
        unit="-",
        doc="a keyframe at every odometry row (the odometry-only graph is dead reckoning)",
    )
    robust: tuple[str, float] | Mapping[str, tuple[str, float]] | None = option(
        None,
        unit="sigma",
        doc=(
            "one loss for every sensor, or a mapping stream -> loss (the odometry stream, "
            "`odometry` or `wheels`, may be named); k in sigma, defaults Huber 1.345, "
            "Cauchy 2.3849, Tukey 4.6851; null: the sensor blocks' own"
        ),
        parse=robust_option,
        type_name=f"{_LOSS}, or mapping of those",
    )
    slam: bool = option(False, unit="-", doc="landmarks are unknown (smoother and isam2)")
    lag: float = option(10.0, unit="s", doc="fixed_lag: the smoother's window", **_POSITIVE)
    max_iterations: int = option(
        100, unit="-", doc="Levenberg-Marquardt: most iterations", minimum=1
    )
    relative_tolerance: float = option(
        1e-6, unit="-", doc="Levenberg-Marquardt: relative error decrease that stops", **_NONNEG
    )
    covariances: bool = option(True, unit="-", doc="compute marginal covariances (world frame)")
    slam_grid: float = option(
        1.0, unit="m", doc="cell of the landmark initialisation grid", **_POSITIVE
    )
    known_landmark_sigma: float = option(
        1e-6, unit="m", doc="sigma of the prior pinning a mapped landmark", **_POSITIVE
    )
    relinearize_threshold: float = option(
        0.1,
        unit="-",
        doc="isam2, fixed_lag: relinearisation threshold (QR factorisation, see below)",
        **_NONNEG,
    )
    relinearize_skip: int = option(
        10, unit="-", doc="isam2, fixed_lag: updates between relinearisation checks", minimum=1
    )
    odometry_floor: float = option(
        1e-8,
        unit="m^2, rad^2",
        doc="variance added to each pre-integrated odometry covariance",
        **_NONNEG,
    )
    final_relinearizations: int = option(
        3, unit="-", doc="isam2: forced full relinearisations at the end", minimum=1
    )
    odometry_calibration: bool | tuple[float, ...] = option(
        False,
        unit="-, -, rad/s",
        doc=(
            "estimate the odometry's systematic errors as graph variables; true: default "
            "prior sigmas, or the prior sigmas (one per state of the drive)"
        ),
        type_name="bool or list of float",
        **_NONNEG,
    )
    calibration_freeze: Mapping | None = option(
        None,
        unit="-, s",
        doc=(
            "isam2: `{rel_change: r, window: s, min_time: 0, check_every: 10}` (convergence) "
            "or `{sigma: {state: threshold}, check_every: 10}` (absolute); null: off"
        ),
        parse=freeze_option,
        type_name="mapping or null",
    )
    slam_init: str = option(
        "auto",
        unit="-",
        doc="smoother: initial values of a SLAM problem (docs/graph.md: SLAM initial values)",
        choices=SLAM_INITS,
    )

    def for_run(self, estimator: str, sensors: Mapping, source: str) -> GraphOptions:
        """These options for a run of ``estimator`` with the sensor blocks ``sensors``.

        ``robust`` becomes stream -> ``(kind, k)``: one loss applies to every sensor stream;
        the sensor blocks' own ``robust`` fill in the streams the block does not name.

        Raises
        ------
        ConfigError
            ``calibration_freeze`` for an estimator other than isam2, or a ``robust`` stream
            that is neither a sensor nor the odometry, naming ``options.<estimator>.<key>``.
        """
        prefix = f"options.{estimator}"
        if self.calibration_freeze is not None and estimator != "isam2":
            raise ConfigError(
                "only the isam2 estimator freezes calibration states",
                source,
                f"{prefix}.calibration_freeze",
            )
        streams = set(sensors) | set(ODOMETRY_STREAMS)
        if isinstance(self.robust, Mapping):
            losses = dict(self.robust)
            bad = set(losses) - streams
            if bad:
                raise ConfigError(
                    f"robust loss for stream(s) not in sensors: {', '.join(sorted(bad))}",
                    file=source,
                    key=f"{prefix}.robust.{sorted(bad)[0]}",
                )
        elif self.robust is not None:
            losses = {s: self.robust for s in streams - set(ODOMETRY_STREAMS)}
        else:
            losses = {}
        own = {s: b.robust for s, b in sensors.items() if getattr(b, "robust", None) is not None}
        resolved = dataclasses.replace(self, robust=types.MappingProxyType({**own, **losses}))
        object.__setattr__(resolved, "_explicit", explicit(self))
        return resolved
