"""Declarations of the run's blocks: ``motion``, ``initial``, ``robot.encoder``, ``log`` and
``options.output``, ``options.cross_check`` and ``options.status`` (:data:`BLOCK_OPTIONS`,
:data:`RUN_OPTIONS`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from odofuse.declarations.common import _NONNEG, _POSITIVE, DEFAULT_INITIAL_SIGMA, INTEGRATORS
from odofuse.declarations.live import LiveOptions
from odofuse.io.csvlog import REPAIR_DUPLICATES
from odofuse.options import option


@dataclass(frozen=True)
class MotionOptions:
    """``motion``: the odometry error model (Siegwart & Nourbakhsh) and the integrator."""

    integrator: str = option(
        "exact", unit="-", doc="pose integration of one step", choices=INTEGRATORS
    )
    k: float | tuple[float, ...] = option(
        1.0e-4,
        unit="input^2 per input",
        doc="variance per unit of each drive input's travel (one number, or one per input)",
        **_NONNEG,
    )
    k_r: float | None = option(
        None,
        unit="m^2 per m",
        doc="right wheel's k: var(ds_r) = k_r |ds_r| (left/right drives); overrides k",
        **_NONNEG,
    )
    k_l: float | None = option(
        None,
        unit="m^2 per m",
        doc="left wheel's k: var(ds_l) = k_l |ds_l| (left/right drives); overrides k",
        **_NONNEG,
    )
    var_floor: float | tuple[float, ...] = option(
        0.0,
        unit="input^2",
        doc="variance added to each input every step (one number, or one per input)",
        **_NONNEG,
    )
    k_theta_ds: float | None = option(
        None,
        unit="rad^2 per m",
        doc=(
            "heading-input variance per metre travelled (increments, twist); null: k[1]^2/k[0], "
            "the two-wheel robot with the same k (docs/motion.md)"
        ),
        **_NONNEG,
    )
    var_rate: float | tuple[float, ...] = option(
        0.0,
        unit="input^2 per s",
        doc="variance added to each input per second (filters; one number, or one per input)",
        **_NONNEG,
    )
    steer_sigma: float = option(0.01, unit="rad", doc="noise of a steering-angle input", **_NONNEG)
    alphas: tuple[float, float, float, float] | None = option(
        None,
        unit="-",
        doc="Thrun's velocity-model a1..a4 on variances (twist and increments drives)",
        **_NONNEG,
    )


@dataclass(frozen=True)
class InitialOptions:
    """``initial``: the prior on the start pose."""

    pose: tuple[float, float, float] | None = option(
        None, unit="m, m, rad", doc="start pose; null: the log's own start pose, else the origin"
    )
    sigma: tuple[float, float, float] = option(
        DEFAULT_INITIAL_SIGMA,
        unit="m, m, rad",
        doc="standard deviations of the start pose",
        **_NONNEG,
    )


@dataclass(frozen=True)
class EncoderOptions:
    """``robot.encoder``: wheel angles in ``wheels.csv`` are encoder ticks."""

    ticks_per_rev: float = option(
        unit="ticks", doc="ticks per revolution of the encoder shaft", **_POSITIVE
    )
    gear_ratio: float = option(
        1.0, unit="-", doc="encoder revolutions per wheel revolution", **_POSITIVE
    )
    rollover: int | None = option(
        None, unit="ticks", doc="counter period (unwrapped); null: none", **_POSITIVE
    )
    columns: tuple[str, ...] | None = option(
        None, unit="-", doc="the tick columns; null: the drive's wheel inputs"
    )


@dataclass(frozen=True)
class RepairOptions:
    """``log.repair``: how a CSV folder's out-of-order and duplicated rows are repaired."""

    sort: bool = option(False, unit="-", doc="sort rows by t (moved rows counted)")
    duplicates: str = option(
        "drop_exact",
        unit="-",
        doc="rows with a repeated t: error, drop exact copies, keep the first, drop conflicting",
        choices=REPAIR_DUPLICATES,
    )


@dataclass(frozen=True)
class LogOptions:
    """``log`` as a mapping (a bag with its topics)."""

    path: str = option(unit="-", doc="log folder, bag or builtin:NAME (relative to the config)")
    topics: dict[str, str | tuple[str, ...]] | None = option(
        None, unit="-", doc="stream kind -> topic name (or list of topics) of a bag"
    )
    joints: dict[str, str] | None = option(
        None, unit="-", doc="drive input name -> JointState joint name of a bag"
    )
    repair: RepairOptions | None = option(
        None, unit="-", doc="CSV folders: opt-in repair policy for time order and duplicates"
    )
    wheel_inputs: str = option(
        "position",
        unit="-",
        doc="wheels.csv / JointState holds positions, or wheel speeds integrated per row",
        choices=("position", "velocity"),
    )
    max_speed: float = option(
        30.0, unit="m/s", doc="plausibility: a faster odometry step is an error", **_POSITIVE
    )
    max_yaw_rate: float = option(
        4.0 * math.pi,
        unit="rad/s",
        doc="plausibility: a faster-turning odometry step is an error",
        **_POSITIVE,
    )


@dataclass(frozen=True)
class OutputOptions:
    """``options.output``: the ROS 2 replay file ``trajectory.mcap`` of a run."""

    mcap: bool | None = option(
        None, unit="-", doc="write trajectory.mcap; null: when the log is a ROS 2 bag"
    )
    topic: str = option("/odometry/filtered", unit="-", doc="topic of the nav_msgs/Odometry")
    map_frame: str = option("map", unit="-", doc="REP-105 map frame id")
    odom_frame: str | None = option(
        None, unit="-", doc="REP-105 odom frame id; null: the bag's Odometry frame, else odom"
    )
    base_frame: str | None = option(
        None, unit="-", doc="robot frame id; null: the bag's child_frame_id, else base_link"
    )


#: Values of ``options.cross_check.smoother``.
CROSS_CHECK_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class CrossCheckOptions:
    """``options.cross_check``: an offline run's second opinion from the batch smoother.

    ``odofuse run`` / ``odofuse batch`` also run the batch smoother on the same log and config
    and compare (:mod:`odofuse.status.cross_check`, docs/trust.md). ``auto`` checks when the config
    fuses an absolute sensor and the log has at most ``max_odometry_steps`` odometry steps:
    on a 1 h log of 50 Hz odometry and 1 Hz GPS the smoother took 18.5 s (the EKF 10.4 s), so
    the default (200,000 steps) checks a 1 h 50 Hz log (180,000) and skips a 10 h one.
    """

    smoother: str = option(
        "auto",
        unit="-",
        doc="compare with the batch smoother of the same log: auto (absolute sensor and a "
        "bounded log), on, off",
        choices=CROSS_CHECK_MODES,
    )
    max_odometry_steps: int = option(
        200_000,
        unit="steps",
        doc="auto: largest log (odometry steps) checked; 200,000 covers 1 h at 50 Hz",
        **_POSITIVE,
    )


@dataclass(frozen=True)
class StatusOptions:
    """``options.status``: what ``status: ok`` promises (docs/trust.md, "The promise").

    ``alpha_run`` is the run's false-alarm rate: on a log that matches its config, the
    probability that the run says ``degraded``. It is split between the checks that can fire
    on such a log (Bonferroni: each check's share is stated in ``metrics.json``
    ``alpha``, and the shares sum to at most ``alpha_run``;
    :func:`odofuse.status.cross_check.alpha_budget`).
    """

    alpha_run: float = option(
        0.05,
        unit="-",
        doc="false-alarm probability of status: degraded per run on a log that matches the "
        "config, split over the checks (docs/trust.md)",
        minimum=1e-9,
        maximum=0.5,
    )
    latency_alpha: float = option(
        1e-3,
        unit="-",
        doc="false-alarm probability per absolute stream of the time-stamp test (a reading "
        "stamped late or early; odofuse.status.latency)",
        minimum=1e-12,
        maximum=0.5,
    )


#: ``options.<name>`` blocks that configure the run rather than an estimator.
RUN_OPTIONS: dict[str, type] = {
    "output": OutputOptions,
    "cross_check": CrossCheckOptions,
    "status": StatusOptions,
}

#: Config block -> options class.
BLOCK_OPTIONS: dict[str, type] = {
    "motion": MotionOptions,
    "initial": InitialOptions,
    "robot.encoder": EncoderOptions,
    "log": LogOptions,
    "live": LiveOptions,
}
