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
import types
from collections.abc import Mapping
from dataclasses import dataclass

from odofuse.declarations.common import _NONNEG, _OPEN_UNIT, _POSITIVE, robust_loss
from odofuse.declarations.filters import odometry_calibration_auto
from odofuse.declarations.sensors import absolute_streams
from odofuse.errors import ConfigError
from odofuse.options import explicit, from_mapping, option, to_mapping

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


@dataclass(frozen=True)
class FreezeThresholds:
    """``calibration_freeze`` by absolute thresholds: freeze a sensor once every one of its
    calibration states' marginal sigma is below its threshold."""

    sigma: dict[str, float] = option(
        unit="state's unit", doc="calibration state -> sigma threshold", **_POSITIVE
    )
    check_every: int = option(10, unit="updates", doc="iSAM2 updates between checks", minimum=1)


@dataclass(frozen=True)
class FreezeConvergence:
    """``calibration_freeze`` by convergence: freeze a sensor once each of its calibration
    sigmas shrank by less than ``rel_change`` over the last ``window`` s of log time."""

    rel_change: float = option(
        unit="-",
        doc="largest relative shrink over the window that counts as converged",
        **_OPEN_UNIT,
    )
    window: float = option(unit="s", doc="log time over which the shrink is measured", **_POSITIVE)
    min_time: float = option(
        0.0, unit="s", doc="log time after the first keyframe before any freeze", **_NONNEG
    )
    check_every: int = option(10, unit="updates", doc="iSAM2 updates between checks", minimum=1)


def freeze_option(value, key: str, source: str):
    """Validate ``calibration_freeze`` (isam2 only) into one of two read-only forms.

    Absolute thresholds (:class:`FreezeThresholds`): ``{sigma: {state: threshold},
    check_every}``; convergence (:class:`FreezeConvergence`): ``{rel_change, window, min_time,
    check_every}``. Exactly one of ``sigma`` and ``rel_change`` must be given. Returns the
    validated, default-filled keys as a read-only mapping (the form
    :mod:`odofuse.estimators.graph.isam2` reads).
    """
    form = "{sigma: {state: threshold}} or {rel_change: r, window: s}"
    if not isinstance(value, Mapping):
        raise ConfigError(f"expected {form}, got {value!r}", source, key)
    if "sigma" in value and "rel_change" in value:
        raise ConfigError(
            "give either sigma (absolute thresholds) or rel_change (convergence), not both",
            source,
            f"{key}.rel_change",
        )
    if "sigma" not in value and "rel_change" not in value:
        raise ConfigError(f"expected {form}, got {value!r}", source, key)
    cls = FreezeThresholds if "sigma" in value else FreezeConvergence
    spec = to_mapping(from_mapping(cls, value, key, source))
    if "sigma" in spec:
        spec["sigma"] = types.MappingProxyType(spec["sigma"])
    return types.MappingProxyType(spec)


def _odometry_calibration(value, key: str, source: str):
    """``auto``, a bool, or a list of non-negative prior sigmas (as a tuple)."""
    if value == "auto" or isinstance(value, bool):
        return value
    if isinstance(value, list | tuple) and all(
        isinstance(v, int | float) and not isinstance(v, bool) and v >= 0 for v in value
    ):
        return tuple(float(v) for v in value)
    raise ConfigError(
        f"must be auto, true, false or a list of prior sigmas, got {value!r}", source, key
    )


#: Sensor kinds whose readings observe landmarks: with ``slam`` they are unknowns.
SLAM_KINDS = ("range", "bearing", "range_bearing")


def gate_loss(gate: float, dim: int) -> tuple[str, float]:
    """The graph's default loss of an absolute sensor with chi-square gate ``gate``: Tukey's
    biweight at ``k = sqrt(chi2_dim(gate))``, whose influence is zero from the distance the
    filters' gate rejects at (GTSAM weighs the whitened distance of the whole reading)."""
    from odofuse.chi2 import ppf

    return ("tukey", float(ppf(gate, dim)) ** 0.5)


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
    partial_relinearization_check: bool = option(
        True,
        unit="-",
        doc=(
            "smoother with slam (its initial iSAM2 pass) and isam2: check for "
            "relinearisation only in the branches an update touched (GTSAM's "
            "enablePartialRelinearizationCheck; both end at a polished optimum); fixed_lag "
            "keeps the full check"
        ),
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
    odometry_calibration: bool | str | tuple[float, ...] = option(
        "auto",
        unit="-, -, rad/s",
        doc=(
            "estimate the odometry's systematic errors as graph variables; true: default "
            "prior sigmas, or the prior sigmas (one per state of the drive); auto: true when "
            "an absolute sensor is fused (not with slam)"
        ),
        parse=_odometry_calibration,
        type_name="auto, bool or list of float",
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
    slip: bool = option(
        True,
        unit="-",
        doc=(
            "robust odometry: widen a keyframe interval's odometry noise when the fused gyro "
            "disagrees (docs/graph.md: wheel slip)"
        ),
    )
    slip_gate: float = option(
        0.999,
        unit="-",
        doc="chi-square probability of the per-interval gyro-wheel disagreement",
        **_OPEN_UNIT,
    )

    def for_run(
        self, estimator: str, sensors: Mapping, source: str, drive: str | None = None
    ) -> GraphOptions:
        """These options for a run of ``estimator`` with the sensor blocks ``sensors``.

        ``robust`` becomes stream -> ``(kind, k)``: one loss applies to every sensor stream;
        the sensor blocks' own ``robust`` fill in the streams the block does not name; an
        absolute sensor with a gate and no loss from either gets :func:`gate_loss` (the
        filters reject a reading beyond the gate; the graph gives it no influence there).
        ``odometry_calibration: auto`` becomes true or false
        (:func:`~odofuse.declarations.filters.odometry_calibration_auto`, on ``drive``).

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
        gated = {
            s: gate_loss(sensors[s].gate, dim)
            for s, dim in absolute_streams(sensors).items()
            if getattr(sensors[s], "gate", None) is not None
            # with slam the landmarks are unknowns, not references: no gate against them
            and not (self.slam and sensors[s].kind in SLAM_KINDS)
        }
        odo_cal = self.odometry_calibration
        if odo_cal == "auto":
            odo_cal = odometry_calibration_auto(drive, sensors, self.slam)
        resolved = dataclasses.replace(
            self,
            robust=types.MappingProxyType({**gated, **own, **losses}),
            odometry_calibration=odo_cal,
        )
        object.__setattr__(resolved, "_explicit", explicit(self))
        # the streams whose loss is the default gate loss (a pose-graph file drops it)
        object.__setattr__(resolved, "gate_defaults", frozenset(gated) - set(own) - set(losses))
        return resolved
