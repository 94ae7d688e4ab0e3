"""Benchmarks of the factor-graph back end (prints figures and ratios; asserts nothing).

Run: ``python benchmarks/bench_graph.py [plaza|isam2|isam2-ratios|hour|gyro|all] [--custom]
[--seconds S] [--repeat N]``

* ``plaza``: Plaza1 batch smoothing with odofuse (``run_smoother``, no covariances) against a
  minimal hand-written GTSAM script that builds the same graph from the same arrays
  (keyframes at range times + every second, per-step midpoint pre-integration,
  ``BetweenFactorPose2``, ``RangeFactor2D`` to pinned beacons, Huber, GTSAM's LM). Both run
  without range calibration so that both graphs are built-in factors only; ``--custom`` also
  times the calibrated graph (CustomFactor) with GTSAM's own LM against odofuse's Python LM.
  Target ratio <= 1.3.
* ``isam2``: per-update latency (CPU time) of iSAM2 on Plaza1 as the log grows (median / p99
  per quarter, of ``ISAM2.update`` and of the whole per-keyframe step), without calibration,
  with range scale/offset variables, with the absolute-threshold ``calibration_freeze`` on the
  tighter numbers it was set for, the packaged ``configs/plaza1-isam2.yaml`` (shared numbers
  + convergence freeze) with and without its freeze and with odometry calibration (first
  600 s); then a one-hour simulated log (50 Hz odometry, 1 Hz GPS) without and with odometry
  calibration. Each prints the last-to-first-quarter ratio of the median (target <= 1.5),
  and GTSAM's own update on a plain chain of the same length is printed as the reference.
* ``isam2-ratios [--repeat N]``: issue 17's four judged iSAM2 cases (Plaza1 packaged config,
  Plaza1 built-in factors without calibration, the one-hour log without and with odometry
  calibration + freeze), each run N times (default 3): per run the last-to-first-quarter
  ratio of the median ``ISAM2.update`` and whole step and of the whole step's p99 (CPU
  time), then the median of the N ratios (single runs on a shared machine move a quarter's
  median by up to 2x), and how many keyframes left iSAM2's tree online
  (``odofuse.estimators.graph.isam2_window``).
* ``isam2-slam [--repeat N] [--seconds S] [--case plaza|sim|both]``: per-update latency
  (CPU time) of iSAM2 SLAM (``graph.isam2_slam``, landmarks unknown) by quarter of the run,
  N runs (default 3), on Plaza1 with ``configs/plaza1-slam.yaml`` as ``estimator: isam2``
  and on a simulated figure-eight log (:func:`simulate_slam`, ``--seconds``, default 1800)
  with range-bearing sightings of landmarks re-seen on every lap: per run the median / p99 /
  max of ``ISAM2.update`` and of the whole step, per quarter, the last/first ratios, and the
  median of the N ratios; then position RMSE and NEES of the last run.
* ``hour``: a one-hour 100 Hz simulated log (360 000 odometry steps, 1 Hz GPS) smoothed in
  batch; wall time (target <= 60 s) and peak resident memory (target <= 2 GiB).
* ``gyro``: iSAM2 and the fixed-lag smoother on a simulated 100 Hz odometry log (``--seconds``,
  default 300) with 1 Hz GPS and a biased gyro at 0 (none), 100 and 200 Hz (pre-integrated
  between 1 s keyframes): wall time, keyframes, per-update latency of ``ISAM2.update`` /
  ``FixedLagSmoother.update`` (median, p99, max, per quarter) and the ratio of odofuse's whole
  per-keyframe step to GTSAM's own update inside it.
"""

from __future__ import annotations

import copy
import resource
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # runnable from any directory: this checkout's odofuse


def _plaza_config(estimator="smoother", calibrate=False, covariances=False, **options):
    from odofuse.config import RunConfig

    return RunConfig(
        log="builtin:plaza1",
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": [1e-3, 1e-4], "var_floor": [1e-6, 1e-8]},
        estimator=estimator,
        initial={"sigma": [0.1, 0.1, 0.05]},
        sensors={"ranges": {"sigma": 0.5, "calibrate": calibrate, "gate": 0.999}},
        options={estimator: {"robust": {"ranges": "huber"}, "covariances": covariances, **options}},
    )


def minimal_script(log, calibrate=False, same_rule=False, stats=None):
    """A plain GTSAM script building the Plaza1 graph (what a user would write by hand).

    GTSAM's ``optimize()`` with a relative tolerance of 1e-6, or with ``same_rule`` odofuse's
    stopping rule written out (:func:`odofuse.estimators.graph.solvers._gtsam_lm`: a small
    decrease ends the run only when the damping did not fall; ``relative_tolerance`` 1e-6),
    so that both run the same iterations. ``stats`` (a dict) receives the iterations and the
    final graph error."""
    stats = {} if stats is None else stats
    import gtsam

    X = gtsam.symbol_shorthand.X
    L = gtsam.symbol_shorthand.L
    o, r = log.streams["odometry"], log.streams["ranges"]
    t_odo = np.r_[o.t[0] - np.median(np.diff(o.t)), o.t]
    ds, dth = o["ds"], o["dtheta"]
    order = np.argsort(r.t, kind="stable")
    rt, rid, rr = r.t[order], r["id"][order].astype(int), r["range"][order]
    keep = (rt >= t_odo[0]) & (rt <= t_odo[-1])
    rt, rid, rr = rt[keep], rid[keep], rr[keep]
    kt = np.unique(np.r_[t_odo[0], t_odo[-1], rt, np.arange(t_odo[0], t_odo[-1], 1.0)])
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pose = gtsam.Pose2(*log.initial_pose)
    graph.add(
        gtsam.PriorFactorPose2(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas([0.1, 0.1, 0.05]))
    )
    values.insert(X(0), pose)
    # per-step pieces (split at keyframes), first-order covariance propagation
    breaks = np.unique(np.r_[t_odo, kt])
    step = np.clip(np.searchsorted(t_odo, breaks[1:]) - 1, 0, len(ds) - 1)
    frac = np.diff(breaks) / (t_odo[step + 1] - t_odo[step])
    owner = np.searchsorted(kt, breaks[1:]) - 1
    k = 0
    for i in range(1, len(kt)):
        rel, cov = gtsam.Pose2(), np.zeros((3, 3))
        while k < len(owner) and owner[k] == i - 1:
            s, w = ds[step[k]] * frac[k], dth[step[k]] * frac[k]
            inc = gtsam.Pose2(s * np.cos(w / 2), s * np.sin(w / 2), w)
            A = inc.inverse().AdjointMap()
            B = np.array([[np.cos(w / 2), 0.0], [np.sin(w / 2), 0.0], [0.0, 1.0]])
            Q = B @ np.diag([1e-3 * abs(s) + 1e-6 * frac[k], 1e-4 * abs(w) + 1e-8 * frac[k]]) @ B.T
            cov = A @ cov @ A.T + Q
            rel = rel.compose(inc)
            k += 1
        graph.add(
            gtsam.BetweenFactorPose2(
                X(i - 1), X(i), rel, gtsam.noiseModel.Gaussian.Covariance(cov + 1e-8 * np.eye(3))
            )
        )
        pose = pose.compose(rel)
        values.insert(X(i), pose)
    for lid, p in log.landmarks.items():
        values.insert(L(lid), gtsam.Point2(*p))
        graph.add(
            gtsam.PriorFactorPoint2(
                L(lid), gtsam.Point2(*p), gtsam.noiseModel.Isotropic.Sigma(2, 1e-6)
            )
        )
    nm = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(1.345), gtsam.noiseModel.Isotropic.Sigma(1, 0.5)
    )
    ki = np.searchsorted(kt, rt)
    if calibrate:
        C = gtsam.symbol("c", 0)
        values.insert(C, np.array([1.0, 0.0]))
        graph.add(
            gtsam.PriorFactorVector(
                C, np.array([1.0, 0.0]), gtsam.noiseModel.Diagonal.Sigmas([0.05, 0.5])
            )
        )

        def make(z, lm):
            def err(this, v, H):
                p, c = v.atPose2(this.keys()[0]), v.atVector(C)
                dx, dy = p.x() - lm[0], p.y() - lm[1]
                d = np.hypot(dx, dy)
                if H is not None:
                    ct, st = np.cos(p.theta()), np.sin(p.theta())
                    H[0] = c[0] * np.array(
                        [[dx / d * ct + dy / d * st, -dx / d * st + dy / d * ct, 0]]
                    )
                    H[1] = np.array([[d, 1.0]])
                return np.array([c[0] * d + c[1] - z])

            return err

        for j in range(len(rt)):
            graph.add(gtsam.CustomFactor(nm, [X(ki[j]), C], make(rr[j], log.landmarks[rid[j]])))
    else:
        for j in range(len(rt)):
            graph.add(gtsam.RangeFactor2D(X(ki[j]), L(rid[j]), rr[j], nm))
    params = gtsam.LevenbergMarquardtParams()
    if not same_rule:
        params.setRelativeErrorTol(1e-6)
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        result = opt.optimize()
    else:  # odofuse's stopping rule, by hand: a small decrease counts only if lambda held
        params.setRelativeErrorTol(0.0)
        params.setAbsoluteErrorTol(0.0)
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        err, lam = opt.error(), opt.lambda_()
        for _ in range(100):
            opt.iterate()
            new, new_lam = opt.error(), opt.lambda_()
            small = err - new <= 1e-6 * err
            err = min(err, new)
            if small and new_lam >= lam:
                break
            lam = new_lam
        result = opt.values()
    stats["iterations"], stats["error"] = opt.iterations(), graph.error(result)
    return kt, np.array(
        [[result.atPose2(X(i)).x(), result.atPose2(X(i)).y()] for i in range(len(kt))]
    )


def bench_plaza(custom=False):
    """Plaza1 batch smoothing: odofuse's smoother (no covariances, no odometry calibration: the
    graph of the minimal script) against the minimal GTSAM script, the script run to GTSAM's
    own stop and to odofuse's stopping rule (the same iterations: the ratio of the target)."""
    from odofuse.estimators.graph import run_smoother
    from odofuse.evaluation import ate, trajectory_from_stream
    from odofuse.io.builtin import load_builtin
    from odofuse.trajectory import Trajectory

    log = load_builtin("builtin:plaza1")
    gt = trajectory_from_stream(log.groundtruth)
    cases = [False, True] if custom else [False]
    repeats = 3  # best of 3: the machine is shared, the minimum is the least disturbed run
    for calibrate in cases:
        cfg = _plaza_config(calibrate=calibrate, odometry_calibration=False)
        t_ours = t_min = t_same = np.inf
        s_min, s_same = {}, {}
        for _ in range(repeats if not calibrate else 1):
            t0 = time.perf_counter()
            res = run_smoother(log, cfg)
            t_ours = min(t_ours, time.perf_counter() - t0)
            t0 = time.perf_counter()
            kt, xy = minimal_script(log, calibrate, stats=s_min)
            t_min = min(t_min, time.perf_counter() - t0)
            t0 = time.perf_counter()
            minimal_script(log, calibrate, same_rule=True, stats=s_same)
            t_same = min(t_same, time.perf_counter() - t0)
        e_ours = ate(res.trajectory, gt).rmse_m
        e_min = ate(Trajectory(kt, np.c_[xy, np.zeros(len(kt))]), gt).rmse_m
        label = "calibrated (CustomFactor)" if calibrate else "built-in factors"
        x = res.extra
        print(
            f"plaza1 batch, {label}: odofuse {t_ours:.2f} s ({x['iterations']} iterations, "
            f"error {x['final_error']:.6g}, RMSE {e_ours:.3f} m); minimal GTSAM script to "
            f"GTSAM's stop {t_min:.2f} s ({s_min['iterations']} iterations, error "
            f"{s_min['error']:.6g}, RMSE {e_min:.3f} m), to odofuse's rule {t_same:.2f} s "
            f"({s_same['iterations']} iterations, error {s_same['error']:.6g}); ratio "
            f"{t_ours / t_same:.2f} (target <= 1.3; {t_ours / t_min:.2f} against GTSAM's stop)"
        )


def bench_isam2():
    import yaml

    from odofuse.config import config_from_dict
    from odofuse.estimators.graph import isam2, run_isam2
    from odofuse.evaluation import ate, trajectory_from_stream
    from odofuse.io.builtin import load_builtin

    # CPU time of this thread (GTSAM runs single-threaded): the shared machine's load would
    # otherwise enter the per-quarter ratios
    isam2._clock = time.thread_time
    print("iSAM2 latency: CPU time per update (thread_time), per quarter of the run")
    log = load_builtin("builtin:plaza1")
    # the absolute thresholds (formerly packaged, set for the tighter numbers)
    absolute = {"sigma": {"range_scale": 0.003, "range_offset": 0.08}, "check_every": 10}
    cases = (
        ("built-in factors", False, None),
        ("range scale/offset variables", True, None),
        ("range scale/offset variables, absolute-threshold freeze", True, absolute),
        ("packaged config without its freeze", "packaged", None),
        ("packaged config (convergence freeze)", "packaged", "packaged"),
        ("packaged config + odometry calibration, first 600 s", "odometry", "packaged"),
    )
    packaged = yaml.safe_load((REPO / "configs" / "plaza1-isam2.yaml").read_text())
    for label, calibrate, frz in cases:
        run_log = log
        if calibrate in ("packaged", "odometry"):
            d = copy.deepcopy(packaged)
            if frz is None:
                del d["options"]["isam2"]["calibration_freeze"]
            if calibrate == "odometry":  # its latency grows fast: a shorter log
                d["options"]["isam2"]["odometry_calibration"] = True
                t0 = min(float(s.t[0]) for s in log.streams.values() if len(s))
                run_log = log.window(t0, t0 + 600.0)
            cfg = config_from_dict(d, "plaza1-isam2.yaml")
        else:
            extra = {"calibration_freeze": frz} if frz else {}
            cfg = _plaza_config("isam2", calibrate=calibrate, **extra)
        t0 = time.perf_counter()
        res = run_isam2(run_log, cfg)
        wall = time.perf_counter() - t0
        rmse = ate(res.trajectory, trajectory_from_stream(run_log.groundtruth)).rmse_m
        print(f"plaza1 iSAM2, {label}: {wall:.1f} s, position RMSE {rmse:.3f} m")
        if frz:
            info = res.extra["calibration_freeze"].get("range_scale")
            if info is None:
                print("  never frozen")
            else:
                t_rel = info["t"] - res.trajectory.t[0]
                print(
                    f"  frozen at keyframe {info['keyframe']} of {len(res.trajectory)} "
                    f"({t_rel:.0f} s into the log)"
                )
        _print_quarters(res)
        if calibrate is False:
            _print_gtsam_chain(len(res.trajectory))
    # a one-hour simulated log (50 Hz odometry, 1 Hz GPS): 3600 keyframes
    log = simulate_hour(rate=50.0)
    for label, calibrated in (("no calibration", False), ("odometry calibration + freeze", True)):
        cfg = _hour_config(calibrated)
        t0 = time.perf_counter()
        res = run_isam2(log, cfg)
        wall = time.perf_counter() - t0
        rmse = ate(res.trajectory, trajectory_from_stream(log.groundtruth)).rmse_m
        print(f"simulated 1 h, 50 Hz, 1 Hz GPS iSAM2, {label}: {wall:.1f} s, RMSE {rmse:.3f} m")
        _print_quarters(res)
    _print_gtsam_chain(len(res.trajectory))


def _hour_config(calibrated: bool):
    """The one-hour log's iSAM2 config, without or with odometry calibration + its freeze."""
    from odofuse.config import RunConfig

    options = (
        {"odometry_calibration": True, "calibration_freeze": {"rel_change": 0.1, "window": 300.0}}
        if calibrated
        else {}
    )
    return RunConfig(
        log="sim",
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": [1e-4, 1e-4], "var_floor": [1e-8, 1e-8]},
        estimator="isam2",
        initial={"pose": [0, 0, 0], "sigma": [0.1, 0.1, 0.05]},
        sensors={"gps": {"sigma": 0.5}},
        options={"isam2": options},
    )


def bench_isam2_ratios(repeat: int = 3) -> None:
    """Issue 17's judged cases, ``repeat`` runs each: last/first-quarter median ratios."""
    from odofuse.config import load_config
    from odofuse.estimators.graph import isam2, run_isam2
    from odofuse.io.builtin import load_builtin

    isam2._clock = time.thread_time  # CPU time of this thread, as in bench_isam2
    plaza, hour = load_builtin("builtin:plaza1"), simulate_hour(rate=50.0)
    cases = (
        (
            "Plaza1, configs/plaza1-isam2.yaml",
            plaza,
            load_config(REPO / "configs" / "plaza1-isam2.yaml"),
        ),
        ("Plaza1, built-in factors, no calibration", plaza, _plaza_config("isam2")),
        ("1 h log, no calibration", hour, _hour_config(False)),
        ("1 h log, odometry calibration + freeze", hour, _hour_config(True)),
    )
    print(f"iSAM2 last/first-quarter median latency (CPU time), {repeat} runs each (target <= 1.5)")
    for label, log, cfg in cases:
        ratios = {"latency": [], "latency_step": [], "p99_step": []}
        for _ in range(repeat):
            res = run_isam2(log, cfg)
            for key in ("latency", "latency_step"):
                q = res.extra[key]["quarters_median_ms"]
                ratios[key].append(q[-1] / q[0])
            p = res.extra["latency_step"]["quarters_p99_ms"]
            ratios["p99_step"].append(p[-1] / p[0])
        print(
            f"  {label}: ISAM2.update",
            " ".join(f"{r:.2f}" for r in ratios["latency"]),
            f"(median {np.median(ratios['latency']):.2f}x); whole step",
            " ".join(f"{r:.2f}" for r in ratios["latency_step"]),
            f"(median {np.median(ratios['latency_step']):.2f}x); whole-step p99",
            " ".join(f"{r:.2f}" for r in ratios["p99_step"]),
            f"(median {np.median(ratios['p99_step']):.2f}x);",
            f"{res.extra.get('marginalised_keyframes', 0)} of {len(res.trajectory)} keyframes",
            f"marginalised online; final LM {res.extra['final_s']:.1f} s",
        )


def simulate_slam(duration=1800.0, seed=0):
    """``(log, config)``: a differential robot driving figure eights (radius 10 m, 1 m/s, one
    lap per 126 s) for ``duration`` s among 16 landmarks, range-bearing sightings within 12 m
    at 1 Hz (seeded ``odofuse.teaching`` simulator); config ``estimator: isam2`` with
    ``slam: true``."""
    import dataclasses

    from odofuse.config import config_from_dict
    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import run_config, to_sensor_log
    from odofuse.teaching.simulate import simulate

    lap = 2 * 2 * np.pi * 10.0 / 1.0
    scenario = {
        "robot": {"drive": "differential", "wheel_radius": 0.1, "track_width": 0.5},
        "path": {
            "kind": "figure_eight",
            "radius": 10.0,
            "speed": 1.0,
            "laps": max(1, int(round(duration / lap))),
        },
        "sensors": {
            "landmarks": {"sigma_range": 0.1, "sigma_bearing": 0.02, "rate": 1.0, "max_range": 12.0}
        },
        "beacons": {"count": 16, "min": [-14.0, -26.0], "max": [14.0, 26.0]},
        "seed": seed,
    }
    sim = simulate(scenario_from_dict(scenario, "<bench scenario>"), seed=seed)
    cfg = run_config(sim, "isam2")
    cfg["options"] = {"isam2": {"slam": True, "covariances": True}}
    config = config_from_dict(cfg, source="<bench config>")
    return to_sensor_log(sim), dataclasses.replace(config, log="<memory>")


def bench_isam2_slam(repeat: int = 3, seconds: float = 1800.0, case: str = "both") -> None:
    """iSAM2 SLAM latency by quarter, ``repeat`` runs per log (issue 17 item 3)."""
    import yaml

    from odofuse.config import config_from_dict
    from odofuse.estimators.graph import isam2, isam2_slam, run_isam2
    from odofuse.evaluation import ate, nees, trajectory_from_stream
    from odofuse.io.builtin import load_builtin

    isam2._clock = isam2_slam._clock = time.thread_time  # CPU time, as in bench_isam2
    d = yaml.safe_load((REPO / "configs" / "plaza1-slam.yaml").read_text())
    d["estimator"] = "isam2"
    d["options"] = {"isam2": {**d["options"].pop("smoother"), "covariances": True}}
    d["options"]["isam2"].pop("keyframe_dt", None)  # isam2 has its own default
    plaza = (load_builtin("builtin:plaza1"), config_from_dict(d, "plaza1-slam.yaml"))
    cases = [("Plaza1, plaza1-slam.yaml as isam2", *plaza)] if case in ("plaza", "both") else []
    if case in ("sim", "both"):
        cases.append((f"simulated figure eight, {seconds:.0f} s", *simulate_slam(seconds)))
    print(f"iSAM2 SLAM latency (CPU time) per quarter, {repeat} runs each (target <= 1.5)")
    for label, log, cfg in cases:
        ratios: dict[str, list] = {}
        for _ in range(repeat):
            t0 = time.perf_counter()
            res = run_isam2(log, cfg)
            wall = time.perf_counter() - t0
            print(
                f"{label}: {wall:.1f} s, {len(res.trajectory)} keyframes, "
                f"{res.extra.get('marginalised_keyframes', 0)} marginalised online"
            )
            _print_quarters(res)
            for key in ("latency", "latency_step"):
                lat = res.extra[key]
                for stat in ("median", "p99"):
                    q = lat[f"quarters_{stat}_ms"]
                    ratios.setdefault(f"{key} {stat}", []).append(q[-1] / q[0])
        print(
            f"  {label}: median over runs of last/first ratio:",
            "; ".join(f"{k} {np.median(v):.2f}x" for k, v in ratios.items()),
        )
        truth = trajectory_from_stream(log.groundtruth)
        e2, e3 = nees(res.trajectory, truth, (0, 1)), nees(res.trajectory, truth)
        aligned = ate(res.trajectory, truth, align=True).rmse_m  # the map's gauge is free
        print(
            f"  accuracy: position RMSE {ate(res.trajectory, truth).rmse_m:.4f} m "
            f"({aligned:.4f} m after SE(2) alignment), "
            f"position NEES {e2:.3f}, pose NEES {e3:.3f}"
        )


def _print_gtsam_chain(n: int) -> None:
    """The reference: GTSAM's own ``ISAM2.update`` on a plain chain of ``n`` built-in
    ``BetweenFactorPose2`` with a built-in unary factor per pose (QR, odofuse's parameters),
    timed like odofuse's updates; its growth is GTSAM's alone."""
    import gtsam

    X = gtsam.symbol_shorthand.X
    params = gtsam.ISAM2Params()
    params.setFactorization("QR")
    isam = gtsam.ISAM2(params)
    odo = gtsam.noiseModel.Diagonal.Sigmas([0.01, 0.01, 0.001])
    unary = gtsam.noiseModel.Diagonal.Sigmas([0.5, 0.5, 10.0])
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), odo))
    v.insert(X(0), gtsam.Pose2())
    isam.update(g, v)
    pose, step, lat = gtsam.Pose2(), gtsam.Pose2(0.5, 0.0, 0.01), []
    for i in range(1, n):
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        pose = pose.compose(step)
        g.add(gtsam.BetweenFactorPose2(X(i - 1), X(i), step, odo))
        g.add(gtsam.PriorFactorPose2(X(i), pose, unary))
        v.insert(X(i), pose)
        t0 = time.thread_time()
        isam.update(g, v)
        lat.append(time.thread_time() - t0)
    q = [float(np.median(a)) * 1e3 for a in np.array_split(np.array(lat), 4)]
    print(
        f"  reference, GTSAM alone on a plain {n}-pose chain: ISAM2.update median per quarter",
        " ".join(f"{m:.2f}" for m in q),
        f"ms; last/first quarter {q[-1] / q[0]:.2f}x",
    )


def _print_quarters(res) -> None:
    """Median / p99 latency per quarter of the run and the last-to-first-quarter ratios."""
    for key, what in (("latency", "ISAM2.update"), ("latency_step", "whole step")):
        lat = res.extra[key]
        q, p = lat["quarters_median_ms"], lat["quarters_p99_ms"]
        print(
            f"  {what:13s} ({lat['updates']} updates): median {lat['median_ms']:.2f} ms, "
            f"p99 {lat['p99_ms']:.2f} ms, max {lat['max_ms']:.1f} ms; per quarter: median",
            " ".join(f"{m:.2f}" for m in q),
            "| p99",
            " ".join(f"{m:.2f}" for m in p),
            f"ms; last/first quarter: median {q[-1] / q[0]:.2f}x (target <= 1.5), "
            f"p99 {p[-1] / p[0]:.2f}x",
        )


def simulate_hour(rate=100.0, duration=3600.0, seed=0):
    """A lawn-mower-like 100 Hz increments log with 1 Hz GPS (seeded)."""
    from odofuse import se2
    from odofuse.io.log import SensorLog, Stream

    rng = np.random.default_rng(seed)
    n = int(rate * duration)
    dt = 1.0 / rate
    t = np.arange(1, n + 1) * dt
    ds_true = np.full(n, 0.5 * dt)
    dth_true = 0.2 * dt * np.sin(2 * np.pi * t / 120.0)
    theta = np.cumsum(dth_true) - dth_true / 2
    xy = np.cumsum(np.column_stack([ds_true * np.cos(theta), ds_true * np.sin(theta)]), axis=0)
    odo = np.column_stack([ds_true + rng.normal(0, 1e-4, n), dth_true + rng.normal(0, 1e-4, n)])
    g = np.arange(int(rate) - 1, n, int(rate))
    gps = xy[g] + rng.normal(0, 0.5, (g.size, 2))
    streams = {
        "odometry": Stream("odometry", "sim", t, ("ds", "dtheta"), odo),
        "gps": Stream("gps", "sim", t[g], ("x", "y"), gps),
    }
    truth = np.column_stack([xy, se2.wrap(np.cumsum(dth_true))])
    gt = Stream("groundtruth", "sim", t, ("x", "y", "theta"), truth)
    return SensorLog("sim-hour", streams, {}, gt, {}, np.zeros(3))


def bench_hour():
    from odofuse.config import RunConfig
    from odofuse.estimators.graph import run_smoother
    from odofuse.evaluation import ate, trajectory_from_stream

    log = simulate_hour()
    cfg = RunConfig(
        log="sim",
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": [1e-4, 1e-4], "var_floor": [1e-8, 1e-8]},
        estimator="smoother",
        initial={"pose": [0, 0, 0], "sigma": [0.1, 0.1, 0.05]},
        sensors={"gps": {"sigma": 0.5}},
        options={"smoother": {"robust": {"gps": "huber"}}},
    )
    t0 = time.perf_counter()
    res = run_smoother(log, cfg)
    wall = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # KiB -> GiB
    e = ate(res.trajectory, trajectory_from_stream(log.groundtruth)).rmse_m
    print(
        f"one-hour 100 Hz log ({len(log.streams['odometry'])} steps, {len(res.trajectory)} "
        f"keyframes): {wall:.1f} s (target <= 60), peak RSS {rss:.2f} GiB (target <= 2), "
        f"RMSE {e:.3f} m"
    )


def simulate_gyro(gyro_rate: float, duration=300.0, rate=100.0, seed=0):
    """A 100 Hz increments log with 1 Hz GPS and a gyro (bias 0.01 rad/s) at ``gyro_rate``."""
    import dataclasses

    from odofuse.io.log import Stream

    log = simulate_hour(rate, duration, seed)
    if gyro_rate <= 0:
        return log
    rng = np.random.default_rng(seed + 1)
    gt = log.groundtruth
    tw = np.arange(1.0 / gyro_rate, gt.t[-1], 1.0 / gyro_rate)
    heading = np.interp(tw, gt.t, np.unwrap(gt["theta"]))
    wz = np.gradient(heading, tw) + 0.01 + rng.normal(0.0, 0.005, tw.size)
    streams = {**log.streams, "gyro": Stream("gyro", "sim", tw, ("wz",), wz[:, None])}
    return dataclasses.replace(log, streams=streams)


def bench_gyro(duration=300.0):
    from odofuse.config import RunConfig
    from odofuse.estimators.graph import run_fixed_lag, run_isam2
    from odofuse.evaluation import ate, trajectory_from_stream

    for gyro_rate in (0.0, 100.0, 200.0):
        log = simulate_gyro(gyro_rate, duration)
        sensors = {"gps": {"sigma": 0.5}}
        if gyro_rate:
            sensors["gyro"] = {"sigma": 0.005, "calibrate": True}
        for name, run in (("isam2", run_isam2), ("fixed_lag", run_fixed_lag)):
            cfg = RunConfig(
                log="sim",
                robot={"drive": "increments"},
                motion={"integrator": "exact", "k": [1e-4, 1e-4], "var_floor": [1e-8, 1e-8]},
                estimator=name,
                initial={"pose": [0, 0, 0], "sigma": [0.1, 0.1, 0.05]},
                sensors=sensors,
                options={name: {"keyframe_dt": 1.0}},
            )
            t0 = time.perf_counter()
            res = run(log, cfg)
            wall = time.perf_counter() - t0
            e = ate(res.trajectory, trajectory_from_stream(log.groundtruth)).rmse_m
            n_gyro = len(log.streams["gyro"]) if gyro_rate else 0
            bias = res.extra.get("calibration", {}).get("gyro_bias")
            print(
                f"{name} {duration:.0f} s, gyro {gyro_rate:.0f} Hz ({n_gyro} samples): "
                f"{wall:.2f} s, {res.extra['keyframes']} keyframes, RMSE {e:.3f} m"
                + (f", bias {bias:.4f} rad/s (true 0.01)" if bias is not None else "")
            )
            lat = res.extra["latency"]
            print(
                f"  update ({lat['updates']}): median {lat['median_ms']:.2f} ms, p99 "
                f"{lat['p99_ms']:.2f} ms, max {lat['max_ms']:.1f} ms; p99 per quarter",
                " ".join(f"{m:.2f}" for m in lat["quarters_p99_ms"]),
                "ms",
            )
            step = res.extra.get("latency_step")
            if step:
                ratio = step["median_ms"] / max(lat["median_ms"], 1e-9)
                print(
                    f"  whole step: median {step['median_ms']:.2f} ms, p99 "
                    f"{step['p99_ms']:.2f} ms; step / ISAM2.update (median) {ratio:.2f}"
                )


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 and not sys.argv[1].startswith("-") else "all"
    if what in ("plaza", "all"):
        bench_plaza("--custom" in sys.argv)
    if what in ("isam2", "all"):
        bench_isam2()
    if what == "isam2-ratios":
        n = int(sys.argv[sys.argv.index("--repeat") + 1]) if "--repeat" in sys.argv else 3
        bench_isam2_ratios(n)
    if what == "isam2-slam":
        n = int(sys.argv[sys.argv.index("--repeat") + 1]) if "--repeat" in sys.argv else 3
        secs = float(sys.argv[sys.argv.index("--seconds") + 1]) if "--seconds" in sys.argv else 1800
        case = sys.argv[sys.argv.index("--case") + 1] if "--case" in sys.argv else "both"
        bench_isam2_slam(n, secs, case)
    if what in ("hour", "all"):
        bench_hour()
    if what in ("gyro", "all"):
        seconds = (
            float(sys.argv[sys.argv.index("--seconds") + 1]) if "--seconds" in sys.argv else 300
        )
        bench_gyro(seconds)
