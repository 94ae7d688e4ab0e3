"""The compiled offline core against its floors, as ratios measured in this process (issue 17).

Run from any directory: ``python /path/to/benchmarks/bench_compiled.py [--steps N]
[--ekf-steps M] [--python-steps P]``. Prints a table of throughputs and the ratios the issue
judges, each against a reference run in this process on the same inputs (best of
``--repeats``, interleaved, so load bursts on a shared machine hit both sides alike):

* dead reckoning, ``N`` steps (differential drive, exact arcs, Siegwart wheel noise), pose only
  and with covariance: odofuse (``compiled.dead_reckoning.dead_reckon``, numba) against the
  numpy reference path, numpy written plainly (pose only), a hand-written numba loop, and a
  memory copy of the output array. Targets: within 2x of the numba loop, within 20x of the copy.
  Like for like, the numba loop writes into arrays allocated for the call (``np.empty``, first
  touched by the loop), as odofuse and any function that returns its result must; the same loop
  into arrays already touched by an earlier call (what this benchmark compared against before
  2026-12-01) and odofuse's kernel into those arrays are printed beside it, so the cost of
  first touching the output (page faults) is shown, not hidden.
* offline EKF, ``M`` steps of increments odometry + one gated range update to a beacon with
  range scale/offset states (n = 5, as on Plaza1): odofuse's whole offline run
  (``compiled.ekf.run``: assembling, the kernel, the result and its findings) and its kernel
  alone, against a hand-written numba EKF of the same model, and the pure-Python path
  (Localizer + filterpy, on ``P`` steps). Target: within 3x of the numba EKF.
* particle filter (``--pf-particles``, default 1000): ``--pf-steps`` steps of
  ``ParticleBackend.predict`` + ``update`` (increments odometry, one gated range with
  scale/offset states, as on Plaza1) with ``compiled: on`` against ``off`` from the same seed
  (the same draws), and the whole offline run (``odofuse.estimators.particle.run``) on a
  simulated figure eight with a gyro (relative updates), GPS and ranges, on against off. The
  ratios are the numpy path's time over the compiled one's; the final clouds are compared.

The first run on a machine compiles the kernels (cached on disk afterwards); warm-up calls
keep compilation out of the timings.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the repo

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from odofuse.io.log import SensorLog, Stream  # noqa: E402

R_WHEEL, TRACK, KW = 0.05, 0.3, 2e-4
BEACONS = {0: np.array([20.0, 0.0]), 1: np.array([0.0, 25.0]), 2: np.array([-15.0, -10.0])}
K_INC = (1e-2, 1e-4)


# ----------------------------------------------------------------------------- references
def numpy_plain(U):
    """Pose-only dead reckoning the way a numpy user writes it (exact arcs, cumsum)."""
    ds = R_WHEEL * (U[:, 0] + U[:, 1]) / 2
    dth = R_WHEEL * (U[:, 1] - U[:, 0]) / TRACK
    th = np.concatenate([[0.0], np.cumsum(dth)])
    half = dth / 2
    chord = ds * np.where(half != 0, np.sin(half) / np.where(half != 0, half, 1), 1.0)
    a = th[:-1] + half
    out = np.empty((len(U) + 1, 3))
    out[0] = 0.0
    np.cumsum(chord * np.cos(a), out=out[1:, 0])
    np.cumsum(chord * np.sin(a), out=out[1:, 1])
    out[:, 2] = (th + math.pi) % (2 * math.pi) - math.pi
    return out


@njit(cache=True)
def numba_loop(U, with_cov, poses, covs):
    """Hand-written numba dead reckoning of the same model (differential, exact, Siegwart)."""
    x = y = th = 0.0
    p00 = p01 = p02 = p11 = p12 = p22 = 0.0
    poses[0, 0], poses[0, 1], poses[0, 2] = 0.0, 0.0, 0.0
    for k in range(U.shape[0]):
        ul, ur = U[k, 0], U[k, 1]
        ds = R_WHEEL * (ur + ul) / 2
        dth = R_WHEEL * (ur - ul) / TRACK
        h = 0.5 * dth
        sinc = 1.0 if h == 0.0 else math.sin(h) / h
        a = th + h
        c, s = math.cos(a), math.sin(a)
        dx, dy = ds * sinc * c, ds * sinc * s
        if with_cov:
            dsinc = -h / 3.0 if abs(h) < 1e-4 else (math.cos(h) - sinc) / h
            # F_u columns for (ds, dth), then through (ul, ur): d(ds, dth)/d(ul, ur) =
            # (r/2, -r/b), (r/2, r/b); wheel variances k |r u| / r^2
            j0x, j0y = sinc * c, sinc * s
            j1x = ds * (0.5 * dsinc * c - 0.5 * sinc * s)
            j1y = ds * (0.5 * dsinc * s + 0.5 * sinc * c)
            vl, vr = KW * abs(ul) / R_WHEEL, KW * abs(ur) / R_WHEEL
            alx = R_WHEEL / 2 * j0x - R_WHEEL / TRACK * j1x
            aly = R_WHEEL / 2 * j0y - R_WHEEL / TRACK * j1y
            alt = -R_WHEEL / TRACK
            arx = R_WHEEL / 2 * j0x + R_WHEEL / TRACK * j1x
            ary = R_WHEEL / 2 * j0y + R_WHEEL / TRACK * j1y
            art = R_WHEEL / TRACK
            e0, e1 = -dy, dx
            n00 = p00 + 2 * e0 * p02 + e0 * e0 * p22
            n01 = p01 + e0 * p12 + e1 * p02 + e0 * e1 * p22
            n11 = p11 + 2 * e1 * p12 + e1 * e1 * p22
            n02, n12 = p02 + e0 * p22, p12 + e1 * p22
            p00 = n00 + vl * alx * alx + vr * arx * arx
            p01 = n01 + vl * alx * aly + vr * arx * ary
            p11 = n11 + vl * aly * aly + vr * ary * ary
            p02 = n02 + vl * alx * alt + vr * arx * art
            p12 = n12 + vl * aly * alt + vr * ary * art
            p22 = p22 + vl * alt * alt + vr * art * art
            covs[k + 1, 0, 0], covs[k + 1, 0, 1], covs[k + 1, 0, 2] = p00, p01, p02
            covs[k + 1, 1, 0], covs[k + 1, 1, 1], covs[k + 1, 1, 2] = p01, p11, p12
            covs[k + 1, 2, 0], covs[k + 1, 2, 1], covs[k + 1, 2, 2] = p02, p12, p22
        x += dx
        y += dy
        th = (th + dth + math.pi) % (2 * math.pi) - math.pi
        poses[k + 1, 0], poses[k + 1, 1], poses[k + 1, 2] = x, y, th


@njit(cache=True)
def numba_ekf(U, ids, ranges, bx, by, x, P, sigma2, gate):
    """Hand-written numba EKF: exact-arc prediction of the increments drive with Siegwart noise
    (k |ds|, k |dth|) and a gated scalar range update with scale/offset states (n = 5)."""
    n = 5
    used = 0
    for k in range(U.shape[0]):
        ds, dth = U[k, 0], U[k, 1]
        th = x[2]
        h = 0.5 * dth
        sinc = 1.0 if h == 0.0 else math.sin(h) / h
        a = th + h
        c, s = math.cos(a), math.sin(a)
        dx, dy = ds * sinc * c, ds * sinc * s
        dsinc = -h / 3.0 if abs(h) < 1e-4 else (math.cos(h) - sinc) / h
        f0x, f0y = sinc * c, sinc * s
        f1x = ds * (0.5 * dsinc * c - 0.5 * sinc * s)
        f1y = ds * (0.5 * dsinc * s + 0.5 * sinc * c)
        v0, v1 = 1e-2 * abs(ds), 1e-4 * abs(dth)
        e0, e1 = -dy, dx
        # P <- F P F^T (F = I + e on the theta column), then + F_u V F_u^T on the pose block
        for i in range(n):
            P[0, i] += e0 * P[2, i]
            P[1, i] += e1 * P[2, i]
        for i in range(n):
            P[i, 0] += e0 * P[i, 2]
            P[i, 1] += e1 * P[i, 2]
        P[0, 0] += v0 * f0x * f0x + v1 * f1x * f1x
        P[0, 1] += v0 * f0x * f0y + v1 * f1x * f1y
        P[1, 1] += v0 * f0y * f0y + v1 * f1y * f1y
        P[0, 2] += v1 * f1x
        P[1, 2] += v1 * f1y
        P[2, 2] += v1
        P[1, 0], P[2, 0], P[2, 1] = P[0, 1], P[0, 2], P[1, 2]
        x[0] += dx
        x[1] += dy
        x[2] = (th + dth + math.pi) % (2 * math.pi) - math.pi
        # range update
        b = ids[k]
        ddx, ddy = x[0] - bx[b], x[1] - by[b]
        d = math.hypot(ddx, ddy)
        H = np.array([x[3] * ddx / d, x[3] * ddy / d, 0.0, d, 1.0])
        y = ranges[k] - (x[3] * d + x[4])
        PH = P @ H
        S = H @ PH + sigma2
        if y * y / S > gate:
            continue
        used += 1
        Kg = PH / S
        for i in range(n):
            x[i] += Kg[i] * y
        # Joseph form (I - K H) P (I - K H)^T + K R K^T
        A = P - np.outer(Kg, H @ P)
        P[:, :] = A - np.outer(A @ H, Kg) + sigma2 * np.outer(Kg, Kg)
        x[2] = (x[2] + math.pi) % (2 * math.pi) - math.pi
    return used


# ----------------------------------------------------------------------------- helpers
def best(fns, repeats):
    """Interleaved best-of-``repeats`` wall time of each callable, in seconds."""
    out = [math.inf] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            out[i] = min(out[i], time.perf_counter() - t0)
    return out


def ekf_log(steps, seed=0):
    """A synthetic log: increments odometry at 50 Hz and one range per step (ids cycle)."""
    from odofuse.config import config_from_dict

    rng = np.random.default_rng(seed)
    t = 0.02 * np.arange(1, steps + 1)
    U = np.column_stack([rng.uniform(0.002, 0.006, steps), rng.normal(0.0, 0.001, steps)])
    ids = np.arange(steps) % 3
    # ranges from the odometry's own path (the filter's model is right), sigma 0.5 m
    th = np.cumsum(U[:, 1])
    xy = np.cumsum(
        U[:, :1] * np.column_stack([np.cos(th - U[:, 1] / 2), np.sin(th - U[:, 1] / 2)]), 0
    )
    b = np.array([BEACONS[i] for i in range(3)])[ids]
    ranges = np.hypot(*(xy - b).T) + rng.normal(0.0, 0.5, steps)
    log = SensorLog(
        "bench",
        {
            "odometry": Stream("odometry", "bench", t, ("ds", "dtheta"), U),
            "ranges": Stream("ranges", "bench", t, ("id", "range"), np.c_[ids, ranges]),
        },
        BEACONS,
        None,
        {},
        np.zeros(3),
    )
    cfg = config_from_dict(
        {
            "log": "bench",
            "robot": {"drive": "increments"},
            "motion": {"integrator": "exact", "k": list(K_INC), "k_theta_ds": 0.0},
            "estimator": "ekf",
            "initial": {"sigma": [0.3, 0.3, 0.1]},
            "sensors": {"ranges": {"sigma": 0.5, "gate": 0.999, "calibrate": True}},
            "options": {"ekf": {"compiled": "on"}},
        },
        "bench.yaml",
    )
    return log, cfg, U, ids.astype(np.int64), ranges


def load():
    try:
        return f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        return "load unknown"


def main(argv=None) -> dict:
    from odofuse.declarations import INTEGRATORS
    from odofuse.drives import Differential
    from odofuse.estimators.compiled import ekf as compiled_ekf
    from odofuse.estimators.compiled import kernels
    from odofuse.estimators.compiled.dead_reckoning import dead_reckon, linear_terms
    from odofuse.motion import MotionModel, OdometryErrorModel
    from odofuse.motion import dead_reckon as numpy_reference

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=10_000_000, help="dead-reckoning steps")
    p.add_argument("--ekf-steps", type=int, default=1_000_000, help="offline EKF steps")
    p.add_argument("--python-steps", type=int, default=5_000, help="Python EKF steps")
    p.add_argument("--pf-particles", type=int, default=1000, help="particles")
    p.add_argument("--pf-steps", type=int, default=2_000, help="particle predict+update steps")
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args(argv)
    print(f"bench_compiled: {load()} at start")
    N = a.steps
    rng = np.random.default_rng(0)
    U = np.column_stack([rng.uniform(0.5, 1.5, N), rng.uniform(0.5, 1.5, N)])
    model = MotionModel(Differential(R_WHEEL, TRACK), OdometryErrorModel((KW, KW), (0.0, 0.0)))
    P0 = np.zeros((3, 3))
    poses = np.empty((N + 1, 3))
    covs = np.empty((N + 1, 3, 3))
    small = U[:100]
    dead_reckon(model, np.zeros(3), P0, small, mode="on")  # warm up (loads or compiles)
    dead_reckon(model, np.zeros(3), P0, small, with_cov=False, mode="on")
    numba_loop(small, True, poses, covs)
    numba_loop(small, False, poses, covs)
    src_p, dst_p = np.ones_like(poses), np.empty_like(poses)
    rows = {}
    t_odo, t_np, t_plain, t_nb, t_cp, t_nb_touched = best(
        [
            lambda: dead_reckon(model, np.zeros(3), P0, U, with_cov=False, mode="on"),
            lambda: numpy_reference(model, np.zeros(3), P0, U, with_cov=False),
            lambda: numpy_plain(U),
            lambda: numba_loop(U, False, np.empty((N + 1, 3)), covs),
            lambda: np.copyto(dst_p, src_p),
            lambda: numba_loop(U, False, poses, covs),
        ],
        a.repeats,
    )
    rows["dr_pose"] = (t_odo, t_np, t_plain, t_nb, t_cp, t_nb_touched)
    src_c, dst_c = np.ones_like(covs), np.empty_like(covs)
    lin = linear_terms(model)[:3]  # M, K, floor of the drive's linear form
    exact = INTEGRATORS.index("exact")
    t_odo_c, t_np_c, t_nb_c, t_cp_c, t_kern_c, t_nb_touched_c, t_fresh = best(
        [
            lambda: dead_reckon(model, np.zeros(3), P0, U, mode="on"),
            lambda: numpy_reference(model, np.zeros(3), P0, U),
            # like for like: the loop into arrays allocated for this call, as odofuse's
            lambda: numba_loop(U, True, np.empty((N + 1, 3)), np.empty((N + 1, 3, 3))),
            lambda: (np.copyto(dst_c, src_c), np.copyto(dst_p, src_p)),
            # where the time goes: odofuse's kernel and the numba loop into arrays an earlier
            # call touched (no page faults), and allocating + first touching the output alone
            lambda: kernels.dr_linear(np.zeros(3), P0, U, *lin, exact, True, poses, covs),
            lambda: numba_loop(U, True, poses, covs),
            lambda: (np.ones((N + 1, 3)), np.ones((N + 1, 3, 3))),
        ],
        a.repeats,
    )
    rows["dr_cov"] = (t_odo_c, t_np_c, t_nb_c, t_cp_c)
    rows["dr_cov_split"] = (t_kern_c, t_nb_touched_c, t_fresh)
    # check: the compiled and numpy paths agree
    got, gc = dead_reckon(model, np.zeros(3), P0, U[:100_000], mode="on")
    ref, rc = numpy_reference(model, np.zeros(3), P0, U[:100_000])
    dr_err = max(np.abs(got - ref).max(), np.abs(gc - rc).max())

    # ------------------------------------------------------------------ EKF
    M = a.ekf_steps
    log, cfg, Ue, ids, ranges = ekf_log(M)
    bx = np.array([BEACONS[i][0] for i in range(3)])
    by = np.array([BEACONS[i][1] for i in range(3)])
    from odofuse.measurements import gate_threshold

    gate = gate_threshold(0.999, 1)
    small_log, small_cfg, *_ = ekf_log(200)
    compiled_ekf.run(small_log, small_cfg)  # warm up
    x0 = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    P0e = np.diag([0.09, 0.09, 0.01, 0.05**2, 0.5**2])
    numba_ekf(Ue[:10], ids[:10], ranges[:10], bx, by, x0.copy(), P0e.copy(), 0.25, gate)
    state = {}

    def offline():
        state["res"] = compiled_ekf.run(log, cfg)

    def hand():
        state["used"] = numba_ekf(Ue, ids, ranges, bx, by, x0.copy(), P0e.copy(), 0.25, gate)

    t_off, t_hand = best([offline, hand], a.repeats)
    kernel_t = _kernel_time(log, cfg, a.repeats)
    res = state["res"]
    assert res is not None and res.used["ranges"] + res.rejected["ranges"] == M
    Pn = a.python_steps
    plog, pcfg, *_ = ekf_log(Pn)
    from odofuse.estimators.assembly import run_with
    from odofuse.estimators.ekf import make_backend

    (t_py,) = best([lambda: run_with(plog, pcfg, "ekf", make_backend)], 1)
    (t_off_small,) = best([lambda: compiled_ekf.run(plog, pcfg)], a.repeats)
    pf = particle_timings(a.pf_particles, a.pf_steps, a.repeats)

    # ------------------------------------------------------------------ table
    print(f"bench_compiled: {load()} at the end; best of {a.repeats}, interleaved")
    print(f"dead reckoning, {N:.0e} steps (compiled vs numpy reference max diff {dr_err:.1e})")
    hdr = f"  {'path':44s} {'steps/s':>10s}  {'ratio':>8s}  target"
    print(hdr)
    t_odo, t_np, t_plain, t_nb, t_cp, t_nb_touched = rows["dr_pose"]
    out = {}

    def line(name, t, steps, ratio="", target=""):
        print(f"  {name:44s} {steps / t:10.3g}  {ratio:>8s}  {target}")

    line("odofuse compiled, pose only", t_odo, N)
    line("  numpy reference (motion.dead_reckon)", t_np, N, f"{t_np / t_odo:.2f}x slower")
    line("  numpy written plainly", t_plain, N, f"{t_plain / t_odo:.2f}x slower")
    line(
        "  numba loop (fresh output)",
        t_nb,
        N,
        f"{t_odo / t_nb:.2f}x",
        "<= 2x  " + _ok(t_odo / t_nb <= 2),
    )
    line("  numba loop into touched arrays", t_nb_touched, N, f"{t_odo / t_nb_touched:.2f}x")
    line(
        "  memory copy of the poses",
        t_cp,
        N,
        f"{t_odo / t_cp:.1f}x",
        "<= 20x " + _ok(t_odo / t_cp <= 20),
    )
    t_odo_c, t_np_c, t_nb_c, t_cp_c = rows["dr_cov"]
    line("odofuse compiled, with covariance", t_odo_c, N)
    line("  numpy reference (motion.dead_reckon)", t_np_c, N, f"{t_np_c / t_odo_c:.2f}x slower")
    line(
        "  numba loop (fresh output)",
        t_nb_c,
        N,
        f"{t_odo_c / t_nb_c:.2f}x",
        "<= 2x  " + _ok(t_odo_c / t_nb_c <= 2),
    )
    line(
        "  memory copy of poses + covariances",
        t_cp_c,
        N,
        f"{t_odo_c / t_cp_c:.1f}x",
        "<= 20x " + _ok(t_odo_c / t_cp_c <= 20),
    )
    t_kern_c, t_nb_touched_c, t_fresh = rows["dr_cov_split"]
    line("  numba loop into touched arrays", t_nb_touched_c, N, f"{t_odo_c / t_nb_touched_c:.2f}x")
    line(
        "  odofuse kernel alone, into touched arrays",
        t_kern_c,
        N,
        f"{t_kern_c / t_nb_touched_c:.2f}x",
        "of the loop into touched arrays",
    )
    line("  allocating + first touch of the output", t_fresh, N, f"{t_fresh / t_odo_c:.2f} of it")
    print(f"offline EKF, {M:.0e} steps (predict + range update, n = 5)")
    line("odofuse compiled.ekf.run (whole run)", t_off, M)
    line("  its kernel alone", kernel_t, M, f"{kernel_t / t_off:.2f} of it")
    line(
        "  hand-written numba EKF",
        t_hand,
        M,
        f"{t_off / t_hand:.2f}x",
        "<= 3x  " + _ok(t_off / t_hand <= 3),
    )
    line("  kernel vs the numba EKF", kernel_t, M, f"{kernel_t / t_hand:.2f}x")
    line(f"odofuse Python path (Localizer + filterpy), {Pn} steps", t_py, Pn)
    line(f"  compiled on the same {Pn} steps", t_off_small, Pn, f"{t_py / t_off_small:.0f}x faster")
    out.update(
        dr_pose_vs_numba=t_odo / t_nb,
        dr_pose_vs_numba_touched=t_odo / t_nb_touched,
        dr_pose_vs_copy=t_odo / t_cp,
        dr_cov_vs_numba=t_odo_c / t_nb_c,
        dr_cov_vs_copy=t_odo_c / t_cp_c,
        dr_cov_vs_numba_touched=t_odo_c / t_nb_touched_c,
        dr_cov_kernel_vs_numba_touched=t_kern_c / t_nb_touched_c,
        ekf_vs_numba=t_off / t_hand,
        ekf_kernel_vs_numba=kernel_t / t_hand,
        python_vs_compiled=t_py / t_off_small,
    )
    n_pf, S = a.pf_particles, a.pf_steps
    print(f"particle filter, {n_pf} particles (numpy path / compiled, same seed and draws)")
    t_on, t_np = pf["step"]
    line(f"compiled predict + range update, {S} steps", t_on, S)
    line("  numpy path on the same draws", t_np, S, f"{t_np / t_on:.2f}x slower")
    print(f"  same final cloud: max |X_on - X_off| = {pf['step_diff']:.1e}")
    t_on, t_np = pf["run"]
    steps = pf["run_steps"]
    line(f"compiled offline run, figure eight ({steps} steps)", t_on, steps)
    line("  numpy path (compiled: off)", t_np, steps, f"{t_np / t_on:.2f}x slower")
    print(f"  same trajectory: max |pose_on - pose_off| = {pf['run_diff']:.1e}")
    out.update(
        pf_step_numpy_vs_compiled=pf["step"][1] / pf["step"][0],
        pf_run_numpy_vs_compiled=pf["run"][1] / pf["run"][0],
    )
    return out


PF_SCENARIO = {
    "seed": 3,
    "dt": 0.02,
    "robot": {"drive": "differential", "wheel_radius": 0.04, "track_width": 0.235},
    "path": {"kind": "figure_eight", "radius": 3.0, "speed": 0.5, "laps": 1},
    "systematic": {"E_d": 1.004, "E_b": 1.01},
    "nonsystematic": {"k": 1.0e-5},
    "sensors": {
        "gyro": {"sigma": 0.005, "bias": 0.01, "rate": 25.0},
        "gps": {"sigma": 0.3, "rate": 1.0},
        "ranges": {"sigma": 0.1, "rate": 5.0, "max_range": 15.0},
    },
    "beacons": [[1, 0.0, 6.0], [2, 0.0, -6.0], [3, 8.0, 0.0], [4, -8.0, 0.0]],
}


def particle_timings(particles, steps, repeats) -> dict:
    """Particle filter, compiled against numpy from the same seed: ``step`` (predict + update
    loop) and ``run`` (the whole offline run on a simulated log) as ``(t_on, t_off)``."""
    import dataclasses

    from odofuse.config import config_from_dict
    from odofuse.estimators.assembly import build
    from odofuse.estimators.particle import make_backend
    from odofuse.estimators.particle import run as run_pf
    from odofuse.teaching.scenario import scenario_from_dict
    from odofuse.teaching.simlog import run_config, to_sensor_log
    from odofuse.teaching.simulate import simulate

    log, _, U, ids, ranges = ekf_log(steps)
    rows = [{"id": float(i), "range": float(r)} for i, r in zip(ids, ranges, strict=True)]

    def pf_config(mode):
        _, cfg, *_ = ekf_log(2)
        opts = {"particles": particles, "seed": 0, "compiled": mode}
        return dataclasses.replace(
            cfg, estimator="particle", options={"particle": _particle_options(opts)}
        )

    def loop(mode, keep):
        loc, _, _ = build(pf_config(mode), log, "particle", make_backend)
        b, model = loc.backend, loc.models["ranges"]
        for k in range(steps):
            b.predict(U[k], 0.02)
            b.update(model, rows[k])
        keep[mode] = b.X

    clouds = {}
    loop("on", clouds)  # warm up: load (or compile) the kernels
    step = best([lambda: loop("on", clouds), lambda: loop("off", clouds)], repeats)
    sim = simulate(scenario_from_dict(PF_SCENARIO, "<bench>"), seed=3)
    slog = to_sensor_log(sim)
    raw = run_config(sim, "particle")
    raw["options"] = {"particle": {"particles": particles, "odometry_calibration": True}}
    results = {}

    def whole(mode):
        raw["options"]["particle"]["compiled"] = mode
        results[mode] = run_pf(slog, config_from_dict(raw, "<bench>"))

    whole("on")
    run = best([lambda: whole("on"), lambda: whole("off")], repeats)
    on, off = results["on"].trajectory.poses, results["off"].trajectory.poses
    return {
        "step": step,
        "step_diff": _pose_diff(clouds["on"], clouds["off"]),
        "run": run,
        "run_steps": len(on) - 1,
        "run_diff": _pose_diff(on, off),
    }


def _pose_diff(a, b) -> float:
    """Largest entry of ``a - b`` (rows of states), the heading difference wrapped."""
    d = a - b
    d[:, 2] = (d[:, 2] + math.pi) % (2 * math.pi) - math.pi
    return float(np.abs(d).max())


def _particle_options(opts):
    from odofuse.declarations import ParticleOptions
    from odofuse.options import coerce

    return coerce(ParticleOptions, opts, "options.particle")


def _ok(flag: bool) -> str:
    return "met" if flag else "MISSED"


def _kernel_time(log, cfg, repeats):
    """Wall time of :func:`kernels.ekf_offline` alone on the run's arrays (monkeypatched in)."""
    from odofuse.estimators.compiled import kernels

    real = kernels.ekf_offline
    spent = []

    def timed(*args):
        t0 = time.perf_counter()
        real(*args)
        spent.append(time.perf_counter() - t0)

    from odofuse.estimators.compiled import ekf as compiled_ekf

    kernels.ekf_offline = timed
    try:
        for _ in range(repeats):
            compiled_ekf.run(log, cfg)
    finally:
        kernels.ekf_offline = real
    return min(spent)


if __name__ == "__main__":
    main()
