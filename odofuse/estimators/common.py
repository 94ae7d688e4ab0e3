"""What every estimator needs from a log and a config: odometry inputs, the initial state and
the augmented state layout (calibration and clone states of the measurement models)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from odofuse.declarations import DEFAULT_INITIAL_SIGMA  # noqa: F401 - re-exported
from odofuse.errors import ConfigError, InputError


def odometry_stream_name(model) -> str:
    """``"odometry"`` for the ``increments`` drive (odometry.csv), ``"cmd_vel"`` for drives
    whose inputs are all velocities (the ``twist`` drive, cmd_vel.csv), else ``"wheels"``."""
    if model.drive.name == "increments":
        return "odometry"
    if set(getattr(model.drive, "input_kinds", ())) == {"velocity"}:
        return "cmd_vel"
    return "wheels"


def odometry_inputs(log, model) -> tuple[np.ndarray, np.ndarray]:
    """Per-step drive inputs of a log and the times of the poses they lead to.

    For ``wheels.csv`` (cumulative wheel angles, rad, and steering angles) step ``k`` goes from
    row ``k`` to row ``k+1``: wheel inputs are the differences; a steering angle in row ``k+1``
    is the angle held during the step that ends there (the simulator writes it so; a logger
    that samples the angle at the row's time gives the same up to one step's change).
    For ``odometry.csv`` (increments since the previous row) row ``k``'s increment
    ends at ``t_k``; the initial pose is placed one nominal period before the first row.
    For ``cmd_vel.csv`` (velocities) row ``k``'s command holds until row ``k+1``:
    ``u_k = v_k (t_{k+1} - t_k)`` (the last row's command has no interval and is unused).

    Drives with redundant wheels (``input_groups``, ``wheels_per_side > 1``) are checked by
    :func:`odofuse.motion.side_outliers`; a flagged wheel's increment is replaced by the mean
    of its unflagged side mates for that step (weight 0 in the side's mean, so every filter
    and the smoother, which all read their inputs here, down-weight it alike). When no mate
    is unflagged (two wheels per side) nothing can say which wheel is wrong and the step is
    kept as measured. Counts go to ``log.repairs`` (``wheels.side_outliers``: flagged wheel
    steps, ``wheels.side_outliers_replaced``: replaced ones) and so to ``metrics.json``. The
    replaced value still enters the error model as an independent reading, so that step's
    side variance is optimistic by a factor ``(n - 1) / n`` per replaced wheel.

    Returns
    -------
    t : ndarray (N+1,)
        Times of the initial pose and of the pose after each step.
    U : ndarray (N, n)
        Drive inputs per step, in the order of ``model.drive.input_names``.
    """
    name = odometry_stream_name(model)
    if name not in log.streams or len(log.streams[name]) == 0:
        raise InputError(
            f"the '{model.drive.name}' drive needs a non-empty {name}.csv stream", file=log.source
        )
    stream = log.streams[name]
    missing = [c for c in model.drive.input_names if c not in stream.columns]
    if missing:
        raise InputError(
            f"missing column(s) {', '.join(missing)} for the '{model.drive.name}' "
            f"drive (has {', '.join(stream.columns)})",
            file=stream.source,
            row=1,
            column=missing[0],
        )
    cols = [stream.columns.index(c) for c in model.drive.input_names]
    values = stream.values[:, cols]
    if name == "odometry":
        period = float(np.median(np.diff(stream.t))) if len(stream) > 1 else 0.0
        return np.concatenate([[stream.t[0] - period], stream.t]), values
    if len(stream) < 2:
        raise InputError("wheels.csv needs at least two rows to form a step", file=stream.source)
    kinds = tuple(model.drive.input_kinds)
    if name == "cmd_vel":
        return stream.t.copy(), values[:-1] * np.diff(stream.t)[:, None]
    steering = np.array([kind == "steer" for kind in kinds])
    U = np.where(steering, values[1:], np.diff(values, axis=0))
    if getattr(model.drive, "input_groups", None):
        U = _down_weight_side_outliers(log, model, U)
    return stream.t.copy(), U


def _down_weight_side_outliers(log, model, U: np.ndarray) -> np.ndarray:
    """Replace flagged wheels by their unflagged side mates' mean (see :func:`odometry_inputs`)."""
    from odofuse.motion import side_outliers

    flagged = side_outliers(model, U)
    if not flagged.any():
        return U
    U = U.copy()
    replaced = 0
    for group in model.drive.input_groups:
        g = list(group)
        bad = flagged[:, g]
        good = ~bad
        n_good = good.sum(axis=1)
        fix = bad & (n_good > 0)[:, None]
        if fix.any():
            mean_good = np.sum(np.where(good, U[:, g], 0.0), axis=1) / np.maximum(n_good, 1)
            block = U[:, g]
            block[fix] = np.broadcast_to(mean_good[:, None], block.shape)[fix]
            U[:, g] = block
            replaced += int(fix.sum())
    # The log's own record of repairs (set, not added: repeated calls give the same counts).
    log.repairs["wheels.side_outliers"] = int(flagged.sum())
    log.repairs["wheels.side_outliers_replaced"] = replaced
    return U


def initial_state(config, log) -> tuple[np.ndarray, np.ndarray]:
    """Initial pose and covariance: ``config.initial`` or the log's own start pose, else 0."""
    initial = config.initial
    if initial.pose is not None:
        pose = np.asarray(initial.pose, dtype=float)
    elif log.initial_pose is not None:
        pose = np.asarray(log.initial_pose, dtype=float)
    else:
        pose = np.zeros(3)
    sigma = np.asarray(initial.sigma, dtype=float)
    if pose.shape != (3,) or sigma.shape != (3,) or not np.all(np.isfinite(np.r_[pose, sigma])):
        raise ConfigError(
            "initial.pose and initial.sigma must be 3 finite numbers",
            file=config.source,
            key="initial",
        )
    return pose, np.diag(sigma**2)


def state_layout(models: Mapping[str, object]) -> tuple[list[str], dict[str, int]]:
    """Names of the augmented states (first-seen order) and their index in the state vector."""
    names: list[str] = []
    for m in models.values():
        for s in getattr(m, "calib_states", ()):
            if s not in names:
                names.append(s)
    return names, {s: 3 + i for i, s in enumerate(names)}


def augmented_prior(models, names, pose0, P0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Initial state, covariance and random-walk variances per second of the full state.

    Clone states (``models[..].clones()``) start as copies of their source state.
    """
    n = 3 + len(names)
    x0 = np.zeros(n)
    x0[:3] = pose0
    P = np.zeros((n, n))
    P[:3, :3] = P0
    walk = np.zeros(n)
    for m in models.values():
        prior = m.calib_prior() if hasattr(m, "calib_prior") else {}
        rw = m.calib_walk() if hasattr(m, "calib_walk") else {}
        for s, (value, sigma) in prior.items():
            i = 3 + names.index(s)
            x0[i], P[i, i] = float(value), float(sigma) ** 2
        for s, w in rw.items():
            walk[3 + names.index(s)] = float(w) ** 2
        for s, src in (m.clones() if hasattr(m, "clones") else {}).items():
            i = 3 + names.index(s)
            x0[i] = x0[src]
            P[i, :] = P[src, :]
            P[:, i] = P[:, src]
            P[i, i] = P[src, src]
    return x0, P, walk


def events(log, t, U, streams) -> list[tuple[float, int, str, object]]:
    """All rows of the odometry and measurement streams, stably sorted by time.

    At equal times measurements come before the odometry step ending there, so they are
    applied at their own time rather than replayed. Rows of one stream that go back in time
    (the Plaza range log has two such blocks) simply take their place in time order.
    """
    out: list[tuple[float, int, int, str, object]] = []
    for s in streams:
        if s not in log.streams:
            continue
        st = log.streams[s]
        for i in range(len(st)):
            out.append((float(st.t[i]), 0, len(out), s, i))
    for k in range(len(U)):
        out.append((float(t[k + 1]), 1, len(out), "__odometry__", k))
    out.sort(key=lambda e: (e[0], e[1], e[2]))
    return [(e[0], e[1], e[3], e[4]) for e in out]


def gyrodometry_of(config) -> tuple[str, float] | None:
    """``("gyro", threshold)`` when the gyro sensor block asks for gyrodometry, else None."""
    opts = config.sensors.get("gyro")
    if not getattr(opts, "gyrodometry", False):
        return None
    if opts.threshold is None:
        raise ConfigError(
            "gyrodometry needs a 'threshold' (rad per odometry step)",
            config.source,
            "sensors.gyro.threshold",
        )
    return ("gyro", opts.threshold)


def calibration_index(models, odo_cal) -> dict[str, int]:
    """``{state: index}`` of every augmented state that is not a clone: the models'
    calibration states, then the odometry calibration's (``odo_cal``,
    :mod:`odofuse.estimators.odocal`, or None)."""
    _, index = state_layout(models)
    clones = {s for m in models.values() for s in (m.clones() if hasattr(m, "clones") else {})}
    if odo_cal is not None:
        index.update(zip(odo_cal.names, odo_cal.index, strict=True))
    return {s: i for s, i in index.items() if s not in clones}


def calibration_of(models, odo_cal, x, P) -> dict[str, dict[str, float]]:
    """``{state: {"value", "sigma"}}`` of every augmented state of ``x`` (n,), ``P`` (n, n)
    that is not a clone (:func:`calibration_index`)."""
    import math

    return {
        s: {"value": float(x[i]), "sigma": float(math.sqrt(max(P[i, i], 0.0)))}
        for s, i in calibration_index(models, odo_cal).items()
    }


#: The UKF's square root (``ukf._psd_sqrt`` and the compiled kernel's): a Cholesky pivot
#: ``U_jj^2`` at or below this fraction of its diagonal entry ``A_jj`` is a singular direction
#: (a state that equals another, as a heading clone right after cloning, or one of zero
#: variance), not a genuine one.
SINGULAR_PIVOT = 1e-12


def angle_states(models) -> np.ndarray:
    """Indices of the circular states: theta and the heading clones of ``models``."""
    angles = [2]
    for m in models.values():
        idx = getattr(m, "calib_index", {})
        for s in m.clones() if hasattr(m, "clones") else {}:
            if s in idx:
                angles.append(idx[s])
    return np.array(sorted(set(angles)))


def sensor_kind(config, name) -> str | None:
    """The model kind of the config's sensor ``name``: its ``model``, else its block's kind
    (``loop_closures``), else its name's default (:func:`~odofuse.declarations.stream_kind`)."""
    from odofuse.declarations import stream_kind

    block = config.sensors[name]
    return getattr(block, "model", None) or getattr(block, "kind", None) or stream_kind(str(name))


def absolute_streams(config, log) -> list[str]:
    """The config's sensor streams of an absolute kind (:data:`~odofuse.declarations.sensors.
    ABSOLUTE_KINDS`: they observe the pose against the world) that have readings in ``log``."""
    from odofuse.declarations.sensors import ABSOLUTE_KINDS

    streams = getattr(log, "streams", {}) or {}
    out = []
    for name in config.sensors or {}:
        kind = sensor_kind(config, name)
        if kind in ABSOLUTE_KINDS and name in streams and len(streams[name]):
            out.append(str(name))
    return out


def slam_option(config, estimator: str) -> bool:
    """Whether ``options.<estimator>.slam`` is on (landmarks estimated, not a map)."""
    opts = config.options.get(estimator) if config.options else None
    return bool(getattr(opts, "slam", False))
