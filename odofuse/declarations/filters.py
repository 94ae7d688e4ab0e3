"""Declarations of the recursive estimators' blocks: ``options.dead_reckoning``,
``options.ekf``, ``options.ukf`` and ``options.particle`` (:class:`FilterOptions` holds the keys
every filter shares)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from odofuse.declarations.common import _NONNEG, _OPEN_UNIT, _POSITIVE, DEFAULT_LATE_WINDOW
from odofuse.errors import ConfigError
from odofuse.options import explicit, option


def _compiled_mode(v, key: str, src: str) -> str:
    """``auto``/``on``/``off``; YAML's unquoted ``on``/``off`` arrive as true/false."""
    v = {True: "on", False: "off"}.get(v, v) if isinstance(v, bool) else v
    if v not in ("auto", "on", "off"):
        raise ConfigError(f"must be one of auto, on, off, got {v!r}", src, key)
    return v


def _compiled_option():
    """``compiled``: the numba core (odofuse.estimators.compiled) or the pure-Python path."""
    return option(
        "auto",
        unit="-",
        doc="numba core of offline runs: auto (if numba imports; dead reckoning from 1e6 "
        "steps), on, off (pure Python)",
        parse=_compiled_mode,
        type_name="auto, on or off",
    )


@dataclass(frozen=True)
class DeadReckoningOptions:
    """``options.dead_reckoning``: the gyro-vs-wheels heading check (when a gyro is logged),
    the compiled core and the prior of the odometry's systematic errors."""

    heading_window: float = option(
        1.0,
        unit="s",
        doc="window over which gyro and wheel heading changes are compared",
        **_POSITIVE,
    )
    heading_alpha: float = option(
        1e-3,
        unit="-",
        doc="false-alarm probability of the disagreement test over the run",
        **_POSITIVE,
    )
    bias_sigma: float = option(
        0.01, unit="rad/s", doc="prior sigma of an unmodelled gyro bias in that test", **_NONNEG
    )
    compiled: str = _compiled_option()
    odometry_calibration: bool | str = option(
        "auto",
        unit="-",
        doc=(
            "widen the covariance by the prior of the odometry's systematic errors, "
            "unobserved (as options.ekf.odometry_calibration; docs/filters.md); auto: when "
            "the config has an absolute sensor (the filters then estimate those errors)"
        ),
        parse=lambda v, key, src: odometry_calibration_mode(v, key, src),
        type_name="auto, true or false",
    )
    odometry_calibration_sigma: tuple[float, ...] | None = option(
        None,
        unit="-, -, rad/s",
        doc="prior sigmas of those errors; null: the graph's defaults (docs/filters.md)",
        **_POSITIVE,
    )

    def for_run(self, estimator: str, sensors, source: str, drive: str | None = None):
        """``odometry_calibration: auto`` resolved as the filters' (``FilterOptions.for_run``)."""
        return FilterOptions.for_run(self, estimator, sensors, source, drive)


def odometry_calibration_mode(v, key: str, src: str):
    """``auto``, ``true`` or ``false`` (a graph block also takes a list of prior sigmas)."""
    if v == "auto" or isinstance(v, bool):
        return v
    raise ConfigError(f"must be auto, true or false, got {v!r}", src, key)


#: Drives whose odometry calibration states exist (``odofuse.estimators.graph.calibration``).
CALIBRATED_DRIVES = ("increments", "differential", "skid_steer")


def odometry_calibration_auto(drive: str | None, sensors, slam: bool = False) -> bool:
    """What ``odometry_calibration: auto`` means for a run: on when the drive has calibration
    states and the run fuses an absolute sensor (GPS, compass, ranges, bearings, landmarks at
    known positions: they make the odometry's scale and heading bias observable), off
    otherwise (dead reckoning, wheels with a gyro only, SLAM's unknown landmarks: nothing
    observes them, and the states would only carry their prior)."""
    from odofuse.declarations.sensors import absolute_streams

    return drive in CALIBRATED_DRIVES and not slam and bool(absolute_streams(sensors))


@dataclass(frozen=True)
class FilterOptions:
    """Keys of every recursive filter."""

    late_window: float = option(
        DEFAULT_LATE_WINDOW,
        unit="s",
        doc="measurements up to this late are replayed, older dropped",
        **_NONNEG,
    )
    odometry_calibration: bool | str = option(
        "auto",
        unit="-",
        doc=(
            "estimate the odometry's systematic errors online (increments: ds_scale, "
            "dtheta_scale, dtheta_bias; differential, skid_steer: wheel_radius_ratio, "
            "track_width_scale, wheel_radius_scale); auto: when an absolute sensor is fused"
        ),
        parse=odometry_calibration_mode,
        type_name="auto, true or false",
    )
    odometry_calibration_sigma: tuple[float, ...] | None = option(
        None,
        unit="-, -, rad/s",
        doc="prior sigmas of those states; null: the graph's defaults (docs/filters.md)",
        **_POSITIVE,
    )
    odometry_calibration_walk: tuple[float, ...] | None = option(
        None,
        unit="per sqrt(s)",
        doc="random-walk sigmas of those states; null: 1e-4 (scales), 1e-5 rad/s (bias)",
        **_NONNEG,
    )
    nis_window: int = option(
        20,
        unit="readings",
        doc="window of one sensor's accepted readings for the NIS band check",
        minimum=2,
    )
    nis_alpha: float = option(
        1e-3,
        unit="-",
        doc="false-alarm probability of the NIS band check over a run of any length",
        **_POSITIVE,
    )
    reject_run: int = option(
        5,
        unit="readings",
        doc="consecutive rejections of one stream that mean divergence",
        minimum=1,
    )
    gross_fraction: float = option(
        0.03,
        unit="-",
        doc="share of a gated stream's readings that may be gross (a GNSS fix tens of metres "
        "off) without a fault: the rejection count's null adds it to the gate's own rate",
        minimum=0,
        maximum=1,
        exclusive_maximum=True,
    )
    recovery: bool = option(
        True, unit="-", doc="re-open (inflate the pose covariance) when a stream shows divergence"
    )
    max_inflation: float = option(
        1e6, unit="-", doc="largest pose covariance inflation of one recovery", minimum=1
    )
    max_condition: float = option(
        1e10, unit="-", doc="largest condition number of the pose correlation matrix", minimum=1
    )
    growth_factor: float = option(
        100.0,
        unit="-",
        doc="growth of the position sigma over its running minimum reported",
        minimum=1,
    )
    calib_sigmas: float = option(
        5.0,
        unit="sigma",
        doc="distance from its prior of a calibration at its bound",
        **_POSITIVE,
    )
    slip: bool = option(
        True, unit="-", doc="robust odometry: widen a step's input noise when the gyro disagrees"
    )
    slip_gate: float = option(
        0.999,
        unit="-",
        doc="chi-square probability of the per-step gyro-wheel disagreement",
        **_OPEN_UNIT,
    )
    health_persist: int = option(
        3,
        unit="windows",
        doc=(
            "consecutive NIS windows above their band before a sensor is failing (persistence; "
            "docs/filters.md, Live health)"
        ),
        minimum=1,
    )
    health_recover: int = option(
        3,
        unit="windows",
        doc="consecutive NIS windows inside their band before a failing sensor recovers",
        minimum=1,
    )
    mde_power: float = option(
        0.95,
        unit="-",
        doc="detection probability of the minimal detectable errors in metrics.json",
        **_OPEN_UNIT,
    )

    def for_run(self, estimator: str, sensors, source: str, drive: str | None = None):
        """These options for a run with the sensor blocks ``sensors`` on ``drive``:
        ``odometry_calibration: auto`` resolved (:func:`odometry_calibration_auto`)."""
        if self.odometry_calibration != "auto":
            return self
        on = odometry_calibration_auto(drive, sensors)
        resolved = dataclasses.replace(self, odometry_calibration=on)
        object.__setattr__(resolved, "_explicit", explicit(self))
        return resolved


@dataclass(frozen=True)
class KalmanOptions(FilterOptions):
    """The keys of the EKF and the UKF beyond :class:`FilterOptions`: the calibration drift
    check (:mod:`odofuse.status.drift`), which tests a Kalman filter's calibration estimates
    as the martingales they are (a particle filter's carry Monte Carlo noise that its
    covariance does not hold)."""

    drift_alpha: float = option(
        1e-3,
        unit="-",
        doc="false-alarm probability of the calibration drift check over a run of any length "
        "(0: off)",
        minimum=0,
        maximum=0.5,
    )
    drift_grid: float = option(
        5.0,
        unit="s",
        doc="odometry time between two snapshots of the calibration states that the drift "
        "check compares",
        **_POSITIVE,
    )


@dataclass(frozen=True)
class EkfOptions(KalmanOptions):
    """``options.ekf``: the extended Kalman filter."""

    compiled: str = _compiled_option()


@dataclass(frozen=True)
class UkfOptions(KalmanOptions):
    """``options.ukf``: the unscented Kalman filter (Van der Merwe sigma points)."""

    alpha: float = option(0.5, unit="-", doc="spread of the sigma points", **_POSITIVE)
    beta: float = option(2.0, unit="-", doc="prior knowledge of the distribution (2: Gaussian)")
    kappa: float = option(0.0, unit="-", doc="secondary scaling")
    compiled: str = _compiled_option()


@dataclass(frozen=True)
class ParticleOptions(FilterOptions):
    """``options.particle``: the particle filter."""

    particles: int = option(1000, unit="-", doc="number of particles", minimum=1)
    seed: int = option(0, unit="-", doc="seed of the filter's random generator", **_NONNEG)
    resample_threshold: float = option(
        0.5,
        unit="-",
        doc="resample when the effective sample size falls below this fraction",
        minimum=0,
        maximum=1,
    )
    # 0.1 until session 33: two filter seeds on one log then disagreed by more than their own
    # covariances on 9 of 58 tuning logs (docs/filters.md, "The calibration states' kernel")
    roughening: float = option(
        0.3,
        unit="-",
        doc="Liu-West kernel width h of the calibration states",
        minimum=0,
        maximum=1,
        exclusive_maximum=True,
    )
    regularise: bool = option(
        True, unit="-", doc="regularised resampling: kernel jitter of the pose after resampling"
    )
    bandwidth_scale: float = option(
        1.0,
        unit="-",
        doc="multiplier of Silverman's kernel bandwidth for the pose jitter",
        **_NONNEG,
    )
    compiled: str = option(
        "auto",
        unit="-",
        doc="numba core of the propagation, weighting and moments: auto (if numba imports; "
        "offline from 5e6 particles x log rows), on, off (numpy)",
        parse=_compiled_mode,
        type_name="auto, on or off",
    )
