"""The time-stamp test: does an absolute sensor's reading come late or early?

A reading stamped ``tau`` seconds after it was taken reads ``h(x(t - tau)) ~ h(x(t)) - tau
hdot(t)``: its residual against the estimate correlates with the rate of the predicted
measurement ``hdot = H_pose xdot``. Regressing the residuals ``e_i`` on ``hdot_i`` (weights
``R_i^-1``) estimates the offset,

    a = sum hdot_i^T R_i^-1 e_i,   b = sum hdot_i^T R_i^-1 hdot_i,   tau_hat = -a / b,

and ``z = a / sqrt(b)`` tests ``tau = 0`` (a score test; online time-offset calibration of
visual-inertial systems estimates the same quantity). The residuals are a smoother's, whose
stacked covariance is ``R - H Sigma H^T <= R`` on a log that matches its config, so
``var(a) <= b``: ``|z|`` above the two-sided normal quantile of
``options.status.latency_alpha`` is a false alarm with probability at most that, per stream
(conservative). Each residual is taken against the estimate interpolated to the reading's
time (positions linearly, the heading along the shorter arc). The robot's velocity
``xdot`` comes from the wheels (the dead-reckoned twist, rotated into the map frame by the
estimate's heading). Readings whose residual fails the sensor's own chi-square gate (gross
outliers) are left out; the symmetric truncation keeps ``E a = 0``.

That bound is loose where the estimate absorbs the offset: the batch smoother moves its
poses to meet late readings (on ``benchmarks/bench_status.py``'s late ranges, 0.10-0.16 s of
a 0.5 s shift was left in its residuals), so ``var(a)`` is a fraction of ``b``. The smoother
therefore computes the same score in its own whitened system with its exact variance there
(:mod:`odofuse.estimators.graph.time_offset`, Rao's score test with the poses and
calibrations as nuisance parameters; ``extra["_latency_scores"]``, read by
:func:`score_statistic`; ``method: smoother system`` in ``metrics.json``, with the share of
the offset's information the states ``absorbed``); iSAM2 and fixed-lag use the bound
(``method: bound``).

Which estimates can see it: the graph back ends run it on their own estimate
(:func:`findings`, from :func:`odofuse.estimators.run_estimator`; fixed-lag's window sees
less of the offset). A filter's own residuals cannot: its state follows the late readings
(the estimate lags along the path) and its innovations stay white (measured: ``z`` 0.3 and
-0.9 where the smoother's is -10 and -4, ``benchmarks/bench_status.py`` fault
``range_time_shift``), so the filters take the batch smoother's finding through the
cross-check (:func:`odofuse.status.cross_check.with_reference_findings`): offline only, not in
``Localizer.health()``. docs/trust.md section 1 lists it with its budget.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from odofuse import se2
from odofuse.status.findings import Finding

#: Fewest readings with a moving robot before the test judges a stream.
MIN_READINGS = 20
#: Half-width (s) of the wheels' finite difference giving the robot's twist.
TWIST_HALF_WIDTH = 0.05


def _state(result, model, pose) -> np.ndarray:
    """A full state vector for ``model``'s ``h``/``H`` (bound to its own states): ``pose`` plus
    the run's final calibration values (constants) at their indices."""
    index = getattr(model, "calib_index", {}) or {}
    x = np.zeros(3 + len(index))
    x[:3] = pose
    cal = (result.extra or {}).get("calibration") or {}
    for name, i in index.items():
        v = cal.get(name)  # the filters' {"value", "sigma"}, the graph's plain value
        v = v.get("value") if isinstance(v, dict) else v
        if v is not None:
            x[i] = float(v)
    return x


def dead_reckoned(config, log):
    """The log's dead-reckoned poses (the motion model alone, no covariance) as a
    :class:`~odofuse.trajectory.Trajectory`: where the robot's twist comes from."""
    from odofuse.estimators.common import initial_state, odometry_inputs
    from odofuse.estimators.compiled.dead_reckoning import dead_reckon
    from odofuse.motion import motion_model_from_config
    from odofuse.trajectory import Trajectory

    model = motion_model_from_config(config)
    to, U = odometry_inputs(log, model)
    pose0, P0 = initial_state(config, log)
    poses, _ = dead_reckon(model, pose0, P0, U, with_cov=False)
    return Trajectory(to, poses, None)


def twist(dr, t: np.ndarray) -> np.ndarray:
    """The wheels' body twist ``(vx, vy, omega)`` at times ``t``: central differences over
    :data:`TWIST_HALF_WIDTH` of the dead-reckoned poses ``dr``."""
    from odofuse.trajectory import interpolate_poses

    h = TWIST_HALF_WIDTH
    a = interpolate_poses(dr, t - h)
    b = interpolate_poses(dr, t + h)
    return se2.between(a, b) / (2.0 * h)


def stream_statistic(log, result, stream: str, model, dr) -> dict | None:
    """``{"n", "tau_s", "sd_s", "z"}`` of one stream (``model`` bound to its own states; ``dr``
    the log's :func:`dead_reckoned` poses), or None when fewer than :data:`MIN_READINGS`
    readings can judge."""
    from odofuse.measurements import gate_threshold
    from odofuse.trajectory import interpolate_poses

    traj = result.trajectory
    st = log.streams[stream]
    if len(traj) < 2 or not len(st):
        return None
    t = np.asarray(st.t, dtype=float)
    idx = np.flatnonzero((t >= traj.t[0]) & (t <= traj.t[-1]))
    if len(idx) < MIN_READINGS:
        return None
    poses = interpolate_poses(traj, t[idx])  # the estimate at each reading's time
    v = twist(dr, t[idx])
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    xdot = np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]])
    gate = gate_threshold(getattr(model, "gate", None), int(model.dim))
    residual = getattr(model, "residual", np.subtract)
    x = _state(result, model, poses[0])
    a = b = 0.0
    n = 0
    for j, i in enumerate(idx):
        row = st.row(int(i))
        x[:3] = poses[j]
        hdot = np.atleast_2d(model.H(x, row))[:, :3] @ xdot[j]
        e = np.atleast_1d(residual(model.z(row), model.h(x, row)))
        Ri = np.linalg.inv(np.atleast_2d(model.R(row)))
        Re = Ri @ e
        if not float(e @ Re) <= gate:
            continue
        a += float(hdot @ Re)
        b += float(hdot @ Ri @ hdot)
        n += 1
    if n < MIN_READINGS or not b > 0.0:
        return None
    z = a / math.sqrt(b)
    return {"n": n, "tau_s": -a / b, "sd_s": 1.0 / math.sqrt(b), "z": z, "method": "bound"}


def score_statistic(score: dict | None) -> dict | None:
    """The statistic of a score computed in the batch smoother's own linear system
    (:func:`odofuse.estimators.graph.time_offset.scores`: ``a``, its variance ``info`` under
    the model, times ``scale``), or None when it has too few readings or no information left
    for the offset."""
    if not score or score["n"] < MIN_READINGS or not score["info"] > 0.0:
        return None
    var = score["info"] * score["scale"]
    return {
        "n": score["n"],
        "tau_s": -score["a"] / score["info"],
        "sd_s": math.sqrt(score["scale"] / score["info"]),
        "z": score["a"] / math.sqrt(var),
        "method": "smoother system",
        "absorbed": 1.0 - score["info"] / score["naive"],
    }


#: Estimators that run the test on their own estimate (the graph back ends).
OWN = frozenset({"smoother", "isam2", "fixed_lag"})


def streams(config, log) -> list[str]:
    """The fused absolute streams the test judges: none in a SLAM run (its landmarks are
    states, not a map; the second opinion is skipped too)."""
    from odofuse.estimators.common import absolute_streams, slam_option

    if slam_option(config, config.estimator) or slam_option(config, "smoother"):
        return []
    return absolute_streams(config, log)


def findings(config, log, result) -> tuple[list[Finding], dict]:
    """The test on each of :func:`streams`: its findings (a stream whose
    ``|z|`` exceeds the bound) and ``metrics.json``'s ``extra.time_offset`` block (per stream
    ``tau_s``, ``sd_s``, ``z``, ``bound_z``, ``n``, ``mde_s``: the smallest offset detected
    with probability ``mde_power``)."""
    from odofuse.declarations import FilterOptions
    from odofuse.estimators.common import state_layout
    from odofuse.measurements import measurement_models

    tested = streams(config, log)
    if not tested:
        return [], {}
    alpha = float(config.estimator_options("status").latency_alpha)
    bound = NormalDist().inv_cdf(1.0 - alpha / 2.0)
    power = NormalDist().inv_cdf(float(FilterOptions().mde_power))
    scores = (result.extra or {}).get("_latency_scores") or {}
    models = dr = None  # the bound's inputs, built only when a stream has no score
    out, block = [], {}
    for s in tested:
        st = score_statistic(scores.get(s))
        if st is None and s not in scores:
            models = models or measurement_models(config, log)
            _, index = state_layout({s: models[s]})
            m = models[s].bind(index) if hasattr(models[s], "bind") else models[s]
            dr = dr if dr is not None else dead_reckoned(config, log)
            st = stream_statistic(log, result, s, m, dr)
        if st is None:
            continue
        block[s] = {**st, "bound_z": bound, "mde_s": (bound + power) * st["sd_s"]}
        if abs(st["z"]) > bound:
            late = "late" if st["tau_s"] > 0 else "early"
            out.append(
                Finding(
                    "latency",
                    f"the residuals follow the robot's motion: the time stamps look "
                    f"{abs(st['tau_s']):.3g} s {late} (sd {st['sd_s']:.2g} s, z {st['z']:.3g} "
                    f"beyond +-{bound:.3g}, false alarm {alpha:.2g}, {st['n']} readings); "
                    "check the sensor's time stamps (its clock, header.stamp, a transport "
                    "delay)",
                    sensor=s,
                    figure=float(st["tau_s"]),
                )
            )
    return out, block
