"""Teaching demos: each writes one slide-ready PNG and returns its numbers.

========================  ======================================================================
``integration``           Euler vs Runge-Kutta 2 vs exact integration against the step size
                          (Politecnico slides ``003_73fced8ec7c15fe5.txt``).
``error_growth``          Siegwart's linearised covariance propagation (``004_...``)
                          against a Monte-Carlo cloud, with NEES; where the banana parts from
                          the ellipse for large heading noise.
``systematic``            Systematic vs non-systematic errors on UMBmark squares and the
                          UMBmark correction (``002_88fc37db58155723.txt``, Borenstein & Feng).
``gyrodometry``           Borenstein's gyrodometry over a bump and a slip burst (``002_...``).
``fusion``                Dead reckoning vs EKF vs smoother through a GPS outage.
``drive_zoo``             Each drive's ICR, degree of mobility and inverse kinematics.
========================  ======================================================================

Every demo is ``demo_<name>(out_dir=".", quick=False, seed=0) -> {"png": path, "numbers": dict}``;
``quick`` shrinks sample counts so the test-suite can run them in seconds. Pictures are drawn
on a bare :class:`matplotlib.figure.Figure` (no pyplot state, no display needed).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse import se2

__all__ = [
    "DEMOS",
    "run_demo",
    "demo_integration",
    "demo_error_growth",
    "demo_systematic",
    "demo_gyrodometry",
    "demo_fusion",
    "demo_drive_zoo",
    "gyrodometry",
    "nees_bounds",
    "plot_umbmark",
]

_COLORS = {
    "truth": "black",
    "euler": "tab:red",
    "rk2": "tab:blue",
    "exact": "tab:green",
    "odometry": "tab:red",
    "gyro": "tab:orange",
    "gyrodometry": "tab:blue",
    "dead_reckoning": "tab:red",
    "ekf": "tab:blue",
    "smoother": "tab:green",
    "gps": "tab:gray",
}


# ----------------------------------------------------------------------------- helpers
def _figure(ncols: int = 2, nrows: int = 1, size=(6.0, 5.0)):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size[0] * ncols, size[1] * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _save(fig, out_dir, name: str) -> str:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    fig.savefig(path, dpi=110)
    return str(path)


def _xy_axes(ax, title: str) -> None:
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)


def _ellipse(mean, cov, prob: float = 0.95, points: int = 90) -> np.ndarray:
    """Outline (points, 2) of the ``prob`` confidence ellipse of a 2-D Gaussian."""
    r = math.sqrt(-2.0 * math.log(1.0 - prob))  # chi-square 2 dof quantile, closed form
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    a = np.linspace(0, 2 * math.pi, points)
    circle = np.stack([np.cos(a), np.sin(a)], 1)
    return np.asarray(mean) + r * (circle * np.sqrt(np.clip(w, 0, None))) @ v.T


def nees_bounds(n_runs: int, dim: int = 3, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` bounds of the mean NEES of ``n_runs`` consistent samples.

    ``n_runs * mean NEES`` is chi-square with ``n_runs * dim`` degrees of freedom
    (Bar-Shalom, Li & Kirubarajan, section 5.4).
    """
    from scipy.stats import chi2

    dof = n_runs * dim
    lo = chi2.ppf(0.5 * (1 - prob), dof) / n_runs
    hi = chi2.ppf(0.5 * (1 + prob), dof) / n_runs
    return float(lo), float(hi)


def _robot_marker(ax, pose, size: float, color: str, **kw) -> None:
    x, y, th = pose
    pts = np.array([[size, 0.0], [-0.6 * size, 0.5 * size], [-0.6 * size, -0.5 * size]])
    R = se2.rot(th)[:2, :2]
    tri = pts @ R.T + [x, y]
    ax.fill(tri[:, 0], tri[:, 1], color=color, alpha=0.8, **kw)


# ----------------------------------------------------------------------------- integration
def demo_integration(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Euler vs RK2 vs exact integration: paths at a coarse step and error against step size."""
    from odofuse.motion import integrate

    v, w, T = 0.5, 0.5, 2 * math.pi  # a half circle of radius 1 m
    R = v / w
    truth_end = np.array([R * math.sin(w * T), R * (1 - math.cos(w * T)), w * T])
    steps = np.unique(np.round(np.geomspace(2, 2000, 8 if quick else 16)).astype(int))
    errors = {m: [] for m in ("euler", "rk2", "exact")}
    for n in steps:
        dt = T / n
        tw = np.array([w * dt, v * dt, 0.0])
        for m in errors:
            pose = np.zeros(3)
            for _ in range(n):
                pose = integrate(pose, tw, m)[0]
            errors[m].append(float(np.hypot(*(pose[:2] - truth_end[:2]))))
    dts = T / steps
    slopes = {}
    for m in ("euler", "rk2"):
        e = np.asarray(errors[m])
        fine = dts < 0.3  # asymptotic regime
        slopes[m] = float(np.polyfit(np.log(dts[fine]), np.log(e[fine]), 1)[0])

    fig, axes = _figure(2)
    ax = axes[0, 0]
    a = np.linspace(0, w * T, 200)
    ax.plot(R * np.sin(a), R * (1 - np.cos(a)), color="black", lw=2, label="true arc")
    n_coarse = 6
    dt_c = T / n_coarse
    for m in errors:
        pose = np.zeros(3)
        path = [pose]
        for _ in range(n_coarse):
            pose = integrate(pose, np.array([w * dt_c, v * dt_c, 0.0]), m)[0]
            path.append(pose)
        p = np.array(path)
        ax.plot(p[:, 0], p[:, 1], "o-", color=_COLORS[m], label=f"{m} ({n_coarse} steps)")
    _xy_axes(ax, f"Half circle, v = {v} m/s, ω = {w} rad/s, Δt = {dt_c:.2f} s")
    ax.legend(loc="lower left")
    ax = axes[0, 1]
    for m in errors:
        e = np.maximum(np.asarray(errors[m]), 1e-16)
        label = "exact (round-off only)" if m == "exact" else f"{m} (slope {slopes[m]:.2f})"
        ax.loglog(dts, e, "o-", color=_COLORS[m], label=label)
    ax.loglog(dts, 0.3 * dts, "k:", lw=1, label="O(Δt) reference")
    ax.loglog(dts, 0.05 * dts**2, "k--", lw=1, label="O(Δt²) reference")
    ax.set_xlabel("step size Δt [s]")
    ax.set_ylabel("final position error [m]")
    ax.set_title("Error at the end of the half circle vs step size")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="lower right")
    png = _save(fig, out_dir, "integration")
    i = int(np.argmin(np.abs(dts - 0.1)))
    numbers = {
        "slope_euler": slopes["euler"],
        "slope_rk2": slopes["rk2"],
        "max_error_exact_m": float(max(errors["exact"])),
        "dt_s": float(dts[i]),
        "error_at_dt_euler_m": errors["euler"][i],
        "error_at_dt_rk2_m": errors["rk2"][i],
        "error_at_dt_exact_m": errors["exact"][i],
    }
    return {"png": png, "numbers": numbers}


# ----------------------------------------------------------------------------- error growth
def _error_growth_case(k: float, n_runs: int, seed: int, length: float, integrator: str):
    from odofuse.drives import make_drive
    from odofuse.motion import MotionModel, OdometryErrorModel, dead_reckon
    from odofuse.simulate import Scenario, WheelNoise, simulate

    geometry = {"wheel_radius": 0.04, "track_width": 0.235}
    n_steps = 100
    sc = Scenario(
        geometry=geometry,
        path={"kind": "twists", "values": [[0.0, length / n_steps, 0.0]] * n_steps},
        dt=0.05,
        wheel_noise=WheelNoise(k=k),
    )
    seeds = np.random.default_rng(seed).integers(0, 2**31 - 1, n_runs)
    sims = [simulate(sc, seed=int(s)) for s in seeds]
    truths = np.stack([s.truth for s in sims])  # (runs, N+1, 3)
    model = MotionModel(
        make_drive("differential", **geometry), OdometryErrorModel((k, k), (0.0, 0.0)), integrator
    )
    est, covs = dead_reckon(model, np.zeros(3), np.zeros((3, 3)), sims[0].u_meas)
    e = truths - est[None]
    e[..., 2] = se2.wrap(e[..., 2])
    checkpoints = np.array([n_steps // 4, n_steps // 2, 3 * n_steps // 4, n_steps])
    nees = []
    inside = []
    for c in checkpoints:
        P = covs[c]
        ec = e[:, c]
        nees.append(float(np.mean(np.einsum("ri,ij,rj->r", ec, np.linalg.inv(P), ec))))
        m2 = np.einsum("ri,ij,rj->r", ec[:, :2], np.linalg.inv(P[:2, :2]), ec[:, :2])
        inside.append(float(np.mean(m2 <= -2 * math.log(0.05))))
    return truths, est, covs, checkpoints, nees, inside


def demo_error_growth(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Linearised covariance (Siegwart) vs Monte-Carlo cloud: NEES, and the banana."""
    n_runs = 200 if quick else 1000
    length = 5.0
    cases = {
        "moderate": 5e-7,  # heading sigma at 5 m about 0.01 rad
        "large_heading_noise": 2.5e-3,  # heading sigma at 5 m about 0.67 rad
    }
    lo, hi = nees_bounds(n_runs)
    numbers: dict = {"runs": n_runs, "nees_bounds_95": [lo, hi], "length_m": length}
    fig, axes = _figure(3, size=(5.6, 5.2))
    for ax, (name, k) in zip(axes[0], cases.items(), strict=False):
        truths, est, covs, checkpoints, nees, inside = _error_growth_case(
            k, n_runs, seed, length, "rk2"
        )
        _, _, _, _, nees_exact, _ = _error_growth_case(k, n_runs, seed, length, "exact")
        for j, c in enumerate(checkpoints):
            ax.scatter(
                truths[:, c, 0],
                truths[:, c, 1],
                s=3,
                alpha=0.35,
                color=f"C{j}",
                label=f"Monte-Carlo at s = {est[c, 0]:.2f} m",
            )
            ell = _ellipse(est[c, :2], covs[c][:2, :2])
            ax.plot(
                ell[:, 0],
                ell[:, 1],
                color=f"C{j}",
                lw=2,
                zorder=3,
                label="95 % ellipses (linearised)" if j == len(checkpoints) - 1 else None,
            )
        ax.plot(est[:, 0], est[:, 1], "k-", lw=1, label="odometry estimate")
        sig = math.sqrt(covs[-1][2, 2])
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(True, alpha=0.3)
        verdict = "consistent" if lo <= nees[-1] <= hi else "inconsistent"
        if name == "moderate":
            ax.set_title(
                f"Moderate noise: k = {k:g} m²/m, σθ(end) = {sig:.3f} rad\n"
                f"NEES(end) = {nees[-1]:.2f}, 95 % bounds [{lo:.2f}, {hi:.2f}]: "
                f"{verdict}"
            )
        else:
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(
                f"Large heading noise: k = {k:g} m²/m, σθ(end) = {sig:.2f} rad\n"
                f"banana vs ellipse: NEES(end) = {nees[-1]:.1f} > {hi:.2f}"
            )
        ax.legend(loc="upper left", fontsize=7, markerscale=4)
        numbers[name] = {
            "k": k,
            "sigma_theta_end_rad": sig,
            "nees_rk2": nees,
            "nees_exact": nees_exact,
            "fraction_inside_95_ellipse": inside,
            "consistent_end": bool(lo <= nees[-1] <= hi),
        }
    # NEES at the end against the heading noise: where the linearisation breaks down.
    ks = np.geomspace(1e-7, 2.5e-3, 5 if quick else 9)
    sweep_runs = 100 if quick else 400
    slo, shi = nees_bounds(sweep_runs)
    sig_end, nees_end = [], []
    for k in ks:
        _, _, covs, _, nees, _ = _error_growth_case(float(k), sweep_runs, seed + 1, length, "rk2")
        sig_end.append(math.sqrt(covs[-1][2, 2]))
        nees_end.append(nees[-1])
    ax = axes[0, 2]
    ax.fill_between(
        [min(sig_end) / 1.5, max(sig_end) * 1.5],
        slo,
        shi,
        color="tab:green",
        alpha=0.25,
        label=f"95 % bounds of the mean NEES ({sweep_runs} runs)",
    )
    ax.axhline(3.0, color="tab:green", lw=1, ls="--", label="expected value 3")
    ax.loglog(sig_end, nees_end, "o-", color="tab:purple", label="Monte-Carlo mean NEES")
    ax.set_xlim(min(sig_end) / 1.5, max(sig_end) * 1.5)
    ax.set_xlabel("heading standard deviation at the end, σθ [rad]")
    ax.set_ylabel("mean NEES at the end (3 dof) [-]")
    ax.set_title(f"Where cloud and ellipse part ({length:g} m straight run)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    numbers["sweep"] = {
        "k": ks.tolist(),
        "sigma_theta_end_rad": sig_end,
        "nees_end": nees_end,
        "runs": sweep_runs,
        "nees_bounds_95": [slo, shi],
    }
    png = _save(fig, out_dir, "error_growth")
    return {"png": png, "numbers": numbers}


# ----------------------------------------------------------------------------- systematic
def plot_umbmark(report, side: float, path) -> str:
    """Return errors of a UMBmark report before and after the correction (two panels)."""
    fig, axes = _figure(2, size=(5.5, 5.0))
    for ax, (title, errs, emax) in zip(
        axes[0],
        [
            ("before correction", report.errors_before, report.e_max_before),
            ("after correction", report.errors_after, report.e_max_after),
        ],
        strict=False,
    ):
        for d, color in (("cw", "tab:red"), ("ccw", "tab:blue")):
            e = np.asarray(errs[d]) * 100
            ax.scatter(e[:, 0], e[:, 1], color=color, s=25, label=f"{d.upper()} runs")
            c = e.mean(axis=0)
            ax.plot(*c, "x", color=color, ms=14, mew=3, label=f"{d.upper()} centroid")
        ax.axhline(0, color="k", lw=0.5)
        ax.axvline(0, color="k", lw=0.5)
        ax.set_xlabel("return error x [cm]")
        ax.set_ylabel("return error y [cm]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
        ax.set_title(f"UMBmark {side:g} m square, {title}\nE_max,syst = {100 * emax:.2f} cm")
        ax.legend(loc="best", fontsize=8)
    est = report.estimate
    fig.suptitle(
        f"Estimated E_d = {est.E_d:.5f}, E_b = {est.E_b:.5f}; reduction x{report.reduction:.0f}"
    )
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return str(out)


def demo_systematic(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Systematic vs non-systematic errors on UMBmark squares, and the UMBmark correction."""
    from dataclasses import replace

    from odofuse.calibration import calibrate_umbmark, systematic_return_error, umbmark_runs
    from odofuse.simulate import Scenario, SystematicErrors, WheelNoise

    runs = 4 if quick else 10
    side = 4.0
    base = Scenario(dt=0.05)
    sys_only = replace(
        base, systematic=SystematicErrors(E_d=1.002, E_b=1.01), wheel_noise=WheelNoise(k=1e-8)
    )
    nonsys = replace(base, wheel_noise=WheelNoise(k=5e-7))
    both = replace(sys_only, wheel_noise=WheelNoise(k=5e-7))
    r_sys = umbmark_runs(sys_only, runs, side, seed)
    r_non = umbmark_runs(nonsys, runs, side, seed + 1)
    report = calibrate_umbmark(both, runs, side, seed + 2)

    fig, axes = _figure(2, size=(6.0, 5.5))
    ax = axes[0, 0]
    sq = np.array([[0, 0], [side, 0], [side, side], [0, side], [0, 0]], dtype=float)
    ax.plot(sq[:, 0], sq[:, 1], "k--", lw=1.5, label="commanded (odometry's belief), CCW")
    ax.plot(sq[:, 0], -sq[:, 1], "k:", lw=1.5, label="commanded, CW")
    for d, color in (("ccw", "tab:blue"), ("cw", "tab:red")):
        p = r_sys["paths"][d][0]
        ax.plot(
            p[:, 0],
            p[:, 1],
            color=color,
            lw=2,
            label=f"true path {d.upper()}, E_d = 1.002, E_b = 1.01",
        )
    ax.plot(0, 0, "ko", ms=6)
    _xy_axes(ax, f"Systematic errors bend a {side:g} m square")
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlim(-1.0, 10.0)
    ax.set_ylim(-5.0, 5.0)
    ax.legend(loc="center right", fontsize=7)
    ax = axes[0, 1]
    sets = [
        ("systematic only", r_sys, "o"),
        ("non-systematic only", r_non, "^"),
        ("both, after UMBmark", report.errors_after, "s"),
    ]
    for label, r, marker in sets:
        for d, color in (("cw", "tab:red"), ("ccw", "tab:blue")):
            e = np.asarray(r[d]) * 100
            ax.scatter(
                e[:, 0],
                e[:, 1],
                marker=marker,
                color=color,
                s=30,
                alpha=0.8,
                facecolors="none" if marker == "^" else color,
                label=f"{label}, {d.upper()}",
            )
    ax.axhline(0, color="k", lw=0.5)
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("return error x [cm]")
    ax.set_ylabel("return error y [cm]")
    ax.set_title(
        "Return position errors: systematic errors form\ntwo separated clusters, "
        "random errors scatter around 0"
    )
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    png = _save(fig, out_dir, "systematic")
    spread = np.vstack([r_non["cw"], r_non["ccw"]])
    numbers = {
        "runs_per_direction": runs,
        "e_max_syst_systematic_only_m": systematic_return_error(r_sys["cw"], r_sys["ccw"]),
        "e_max_syst_nonsystematic_only_m": systematic_return_error(r_non["cw"], r_non["ccw"]),
        "nonsystematic_rms_return_error_m": float(np.sqrt(np.mean(np.sum(spread**2, 1)))),
        "umbmark": report.summary(),
    }
    return {"png": png, "numbers": numbers}


# ----------------------------------------------------------------------------- gyrodometry
def gyrodometry(dtheta_odo, dtheta_gyro, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Borenstein's gyrodometry (``002_88fc37db58155723.txt``): per step, trust the gyro only
    where it disagrees with the encoders by more than ``threshold``.

    Parameters
    ----------
    dtheta_odo, dtheta_gyro : array_like (N,)
        Heading change of each step from the encoders and from the gyro, rad.
    threshold : float
        ``Delta theta_thresh``, rad per step.

    Returns
    -------
    dtheta : ndarray (N,)
        ``dtheta_gyro`` where ``|dtheta_gyro - dtheta_odo| > threshold``, else ``dtheta_odo``.
    used_gyro : ndarray (N,) of bool
    """
    odo = np.asarray(dtheta_odo, dtype=float)
    gyro = np.asarray(dtheta_gyro, dtype=float)
    if odo.shape != gyro.shape:
        raise ValueError(f"odometry and gyro increments differ in shape: {odo.shape}, {gyro.shape}")
    used = np.abs(gyro - odo) > threshold
    return np.where(used, gyro, odo), used


def _integrate_ds_dtheta(pose0, ds, dth) -> np.ndarray:
    """Poses (N+1, 3) from per-step distance and heading change (mid-heading, RK2)."""
    th = pose0[2] + np.concatenate([[0.0], np.cumsum(dth)])
    mid = th[:-1] + 0.5 * dth
    xy = pose0[:2] + np.concatenate(
        [np.zeros((1, 2)), np.cumsum(np.column_stack([ds * np.cos(mid), ds * np.sin(mid)]), 0)]
    )
    return np.column_stack([xy, th])


def demo_gyrodometry(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Gyrodometry over a bump and a slip burst: odometry vs gyro vs gyrodometry."""
    from odofuse.drives import make_drive
    from odofuse.simulate import GyroSpec, Scenario, WheelNoise, simulate

    dt = 0.02
    geometry = {"wheel_radius": 0.04, "track_width": 0.235}
    laps = 1 if quick else 2
    sc = Scenario(
        geometry=geometry,
        dt=dt,
        path={"kind": "square", "side": 4.0, "direction": "ccw", "laps": laps, "speed": 0.3},
        wheel_noise=WheelNoise(
            k=1e-7, bumps=((5.0, "right", 0.02),), slip_bursts=((22.0, 23.0, "left", 0.15),)
        ),
        gyro=GyroSpec(sigma=0.003, bias=0.002),
        seed=seed,
    )
    sim = simulate(sc)
    drive = make_drive("differential", **geometry)
    tw = drive.twist(sim.u_meas)
    ds, dth_odo = tw[:, 1], tw[:, 0]
    dth_gyro = sim.streams["gyro"]["wz"] * dt
    gyro_sigma_step = 0.003 * dt
    threshold = max(10 * gyro_sigma_step, 0.002)
    dth_gd, used = gyrodometry(dth_odo, dth_gyro, threshold)
    pose0 = sim.truth[0]
    paths = {
        "odometry": _integrate_ds_dtheta(pose0, ds, dth_odo),
        "gyro": _integrate_ds_dtheta(pose0, ds, dth_gyro),
        "gyrodometry": _integrate_ds_dtheta(pose0, ds, dth_gd),
    }
    truth = sim.truth
    fig, axes = _figure(2, size=(6.0, 5.0))
    ax = axes[0, 0]
    ax.plot(truth[:, 0], truth[:, 1], color="black", lw=2.5, label="ground truth")
    for name, p in paths.items():
        ax.plot(p[:, 0], p[:, 1], color=_COLORS[name], lw=1.5, label=name)
    kb = int(5.0 / dt)
    ax.plot(*truth[kb, :2], "k*", ms=14, label="bump (right wheel, 2 cm)")
    ks = int(22.0 / dt)
    ax.plot(*truth[ks, :2], "kP", ms=11, label="slip burst (left wheel, 15 %, 1 s)")
    _xy_axes(ax, f"{laps} lap(s) of a 4 m square, CCW; gyro bias 0.002 rad/s")
    ax.legend(loc="best", fontsize=8)
    ax = axes[0, 1]
    numbers: dict = {
        "threshold_rad_per_step": threshold,
        "steps": int(len(ds)),
        "steps_using_gyro": int(used.sum()),
    }
    for name, p in paths.items():
        err = np.degrees(se2.wrap(p[:, 2] - truth[:, 2]))
        ax.plot(sim.t, err, color=_COLORS[name], label=name)
        numbers[f"{name}_final_heading_error_deg"] = float(err[-1])
        numbers[f"{name}_final_position_error_m"] = float(np.hypot(*(p[-1, :2] - truth[-1, :2])))
    ax.axvline(5.0, color="k", ls=":", lw=1)
    ax.axvspan(22.0, 23.0, color="k", alpha=0.15, label="slip burst")
    ax.axvline(5.0, color="k", ls=":", lw=1, label="bump")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("heading error [deg]")
    ax.set_title(
        f"Heading error; gyrodometry used the gyro on {int(used.sum())} of {len(ds)} steps"
    )
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    png = _save(fig, out_dir, "gyrodometry")
    return {"png": png, "numbers": numbers}


# ----------------------------------------------------------------------------- fusion
def demo_fusion(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Dead reckoning vs EKF vs smoother through a GPS outage (simulated figure eight)."""
    import tempfile

    from odofuse.config import load_config
    from odofuse.errors import OdofuseError
    from odofuse.estimators import get_estimator
    from odofuse.evaluation import interpolate_poses
    from odofuse.io.loader import load_log_for
    from odofuse.simulate import (
        GpsSpec,
        GyroSpec,
        Scenario,
        SystematicErrors,
        WheelNoise,
        simulate,
        write_log,
    )

    outage = (40.0, 80.0) if quick else (60.0, 120.0)
    sc = Scenario(
        path={"kind": "figure_eight", "radius": 5.0, "speed": 0.5, "laps": 1 if quick else 2},
        dt=0.05 if quick else 0.02,
        systematic=SystematicErrors(E_d=1.002, E_b=1.005),
        wheel_noise=WheelNoise(k=2e-5),
        gyro=GyroSpec(sigma=0.01, rate=10.0),
        gps=GpsSpec(sigma=1.0, rate=1.0, outages=(outage,)),
        encoder=None,
        seed=seed,
    )
    sim = simulate(sc)
    results: dict = {}
    skipped: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        write_log(sim, tmp)
        config = load_config(Path(tmp) / "config.yaml")
        log = load_log_for(config)
        for name in ("dead_reckoning", "ekf", "smoother"):
            try:
                run = get_estimator(name)
            except OdofuseError as exc:
                skipped[name] = str(exc)
                continue
            from dataclasses import replace

            cfg = replace(config, estimator=name)
            if name == "dead_reckoning":
                cfg = replace(cfg, sensors={})
            results[name] = run(log, cfg).trajectory
    t_gt = sim.t
    fig, axes = _figure(2, size=(6.0, 5.0))
    ax = axes[0, 0]
    ax.plot(sim.truth[:, 0], sim.truth[:, 1], color="black", lw=2.5, label="ground truth")
    g = sim.streams["gps"]
    ax.scatter(g["x"], g["y"], s=8, color=_COLORS["gps"], label="GPS fixes (σ = 1 m)")
    inside = (t_gt >= outage[0]) & (t_gt < outage[1])
    ax.plot(
        sim.truth[inside, 0],
        sim.truth[inside, 1],
        color="gold",
        lw=6,
        alpha=0.5,
        label="GPS outage",
        zorder=0,
    )
    numbers: dict = {"outage_s": list(outage), "skipped": skipped}
    ax2 = axes[0, 1]
    for name, traj in results.items():
        ax.plot(
            traj.poses[:, 0],
            traj.poses[:, 1],
            color=_COLORS[name],
            lw=1.5,
            label=name.replace("_", " "),
        )
        gt = interpolate_poses(type(traj)(t_gt, sim.truth), traj.t)
        err = np.hypot(*(traj.poses[:, :2] - gt[:, :2]).T)
        ax2.plot(traj.t, err, color=_COLORS[name], label=name.replace("_", " "))
        during = (traj.t >= outage[0]) & (traj.t < outage[1])
        numbers[name] = {
            "rmse_m": float(np.sqrt(np.mean(err**2))),
            "max_error_in_outage_m": float(err[during].max()) if during.any() else math.nan,
            "final_error_m": float(err[-1]),
        }
    _xy_axes(ax, "Figure eight, wheels + gyro + GPS")
    ax.legend(loc="best", fontsize=8)
    ax2.axvspan(*outage, color="gold", alpha=0.3, label="GPS outage")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("position error [m]")
    ax2.set_yscale("log")
    ax2.set_ylim(bottom=1e-2)
    ax2.set_title("Position error against ground truth")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(loc="best", fontsize=8)
    png = _save(fig, out_dir, "fusion")
    return {"png": png, "numbers": numbers}


# ----------------------------------------------------------------------------- drive zoo
_ZOO = [
    ("differential", {"wheel_radius": 0.05, "track_width": 0.4}, [0.5, 0.25, 0.0]),
    ("skid_steer", {"wheel_radius": 0.1, "track_width": 0.5}, [0.5, 0.5, 0.0]),
    ("synchro", {"wheel_radius": 0.05}, [0.5, 0.5, 0.0]),
    ("tricycle", {"wheel_radius": 0.1, "wheelbase": 0.6}, [0.5, 0.3, 0.0]),
    ("bicycle", {"wheel_radius": 0.3, "wheelbase": 1.0}, [0.25, 0.5, 0.0]),
    ("ackermann", {"wheel_radius": 0.3, "wheelbase": 1.0, "track_width": 0.6}, [0.2, 0.5, 0.0]),
    ("omni3", {"wheel_radius": 0.05, "wheel_distance": 0.2}, [0.5, 0.3, 0.3]),
    ("mecanum4", {"wheel_radius": 0.05, "half_length": 0.2, "half_width": 0.15}, [0.5, 0.0, 0.5]),
    (
        "swerve",
        {"wheel_radius": 0.05, "modules": [[0.3, 0.25], [0.3, -0.25], [-0.3, 0.25], [-0.3, -0.25]]},
        [0.5, 0.3, 0.2],
    ),
    ("car", {"wheel_radius": 0.3, "wheelbase": 1.0, "track_width": 0.6}, [0.25, 0.5, 0.0]),
    ("car_ackermann", {"wheel_radius": 0.3, "wheelbase": 1.0, "track_width": 0.6}, [0.2, 0.5, 0.0]),
]


def _wheel_layout(name: str, geometry: dict, u: np.ndarray) -> list[tuple[float, float, float]]:
    """Wheel centres and rolling directions ``(x, y, heading)`` in the body frame (m, rad).

    Layouts follow the drive docstrings in :mod:`odofuse.drives` (Modern Robotics numbering for
    omni3/mecanum4, body origin at the rear axle midpoint for car-like drives). Steered wheels
    are turned by their inverse-kinematics steering angle. Skid-steer and synchro layouts are
    illustrative (their models have no wheel positions).
    """
    g = geometry
    if name == "differential":
        b = g["track_width"] / 2
        return [(0.0, b, 0.0), (0.0, -b, 0.0)]
    if name == "skid_steer":
        b = g["track_width"] / 2
        return [(sx * 0.5 * b, sy * b, 0.0) for sx in (1, -1) for sy in (1, -1)]
    if name == "synchro":
        r = 4 * g["wheel_radius"]
        return [(r * math.cos(a), r * math.sin(a), 0.0) for a in (0.0, 2.094, 4.189)]
    if name == "tricycle":
        d = g["wheelbase"]
        return [(0.0, 0.3 * d, 0.0), (0.0, -0.3 * d, 0.0), (d, 0.0, float(u[1]))]
    if name == "bicycle":
        return [(0.0, 0.0, 0.0), (g["wheelbase"], 0.0, float(u[1]))]
    if name == "ackermann":
        b, d = g["track_width"] / 2, g["wheelbase"]
        return [(d, b, float(u[4])), (d, -b, float(u[5])), (0.0, b, 0.0), (0.0, -b, 0.0)]
    if name == "omni3":
        d = g["wheel_distance"]
        c = d * math.sqrt(3) / 2
        return [(0.0, d, 0.0), (c, -d / 2, math.radians(240)), (-c, -d / 2, math.radians(120))]
    if name == "mecanum4":
        ll, w = g["half_length"], g["half_width"]
        return [(ll, w, 0.0), (ll, -w, 0.0), (-ll, -w, 0.0), (-ll, w, 0.0)]
    if name == "swerve":
        n = len(g["modules"])
        return [(x, y, float(u[n + i])) for i, (x, y) in enumerate(g["modules"])]
    if name in ("car", "car_ackermann"):
        b, d = g["track_width"] / 2, g["wheelbase"]
        front = (
            [(d, 0.0, float(u[2]))]
            if name == "car"
            else [(d, b, float(u[2])), (d, -b, float(u[3]))]
        )
        return [(0.0, b, 0.0), (0.0, -b, 0.0), *front]
    return []


#: Drives whose wheels roll without side slip: their wheel axes all pass through the ICR.
_AXES_MEET_AT_ICR = (
    "differential",
    "tricycle",
    "bicycle",
    "ackermann",
    "swerve",
    "car",
    "car_ackermann",
)


def _draw_wheels(ax, name, geometry, u, icr, size: float) -> None:
    for x, y, h in _wheel_layout(name, geometry, u):
        c, s_ = math.cos(h), math.sin(h)
        half_l, half_w = 0.5 * size, 0.15 * size
        corners = np.array(
            [[half_l, half_w], [-half_l, half_w], [-half_l, -half_w], [half_l, -half_w]]
        )
        pts = corners @ np.array([[c, s_], [-s_, c]]) + [x, y]
        ax.fill(pts[:, 0], pts[:, 1], color="0.15", zorder=4)
        if name in _AXES_MEET_AT_ICR and np.all(np.isfinite(icr)):
            ax.plot([x, icr[0]], [y, icr[1]], color="tab:red", lw=1, ls="--", zorder=3)


def demo_drive_zoo(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """The drive zoo: each drive's ICR, degree of mobility and inverse kinematics."""
    from odofuse.drives import make_drive

    fig, axes = _figure(4, 3, size=(4.2, 4.2))
    for ax in axes.ravel()[len(_ZOO) :]:
        ax.set_visible(False)
    numbers: dict = {}
    n = 24 if quick else 60
    for ax, (name, geometry, twist) in zip(axes.ravel(), _ZOO, strict=False):
        drive = make_drive(name, **geometry)
        tw = np.asarray(twist, dtype=float)  # per second
        u = np.asarray(drive.inverse(tw), dtype=float)
        back = np.asarray(drive.twist(u), dtype=float)
        icr = np.asarray(drive.icr(tw), dtype=float)
        T = 1.5 * math.pi / abs(tw[0])
        step = se2.exp(tw * T / n)
        poses = [np.zeros(3)]
        for _ in range(n):
            poses.append(se2.compose(poses[-1], step))
        p = np.array(poses)
        ax.plot(p[:, 0], p[:, 1], color="tab:blue", lw=2, label="path under the twist")
        for j in range(0, n + 1, n // 4):
            _robot_marker(ax, p[j], 0.05 * max(1.0, float(np.ptp(p[:, :2]))), "tab:blue")
            ax.plot([p[j, 0], icr[0]], [p[j, 1], icr[1]], color="tab:gray", ls=":", lw=1)
        ax.plot(*icr, "r*", ms=15, label="ICR")
        size = 2.0 * geometry["wheel_radius"]  # wheels to scale
        _draw_wheels(ax, name, geometry, u, icr, size)
        if name in _AXES_MEET_AT_ICR:
            ax.plot([], [], color="tab:red", lw=1, ls="--", label="wheel axes (meet at ICR)")
        dom = int(drive.degree_of_mobility)
        dos = int(getattr(drive, "degree_of_steerability", 0))
        ax.set_title(
            f"{name}: δm = {dom}, δs = {dos}\ntwist ω={tw[0]:g}, vx={tw[1]:g}, vy={tw[2]:g} (1/s)",
            fontsize=10,
        )
        text = "\n".join(f"{k} = {v:+.2f}" for k, v in zip(drive.input_names, u, strict=False))
        ax.text(
            0.02,
            0.02,
            "inverse kinematics:\n" + text,
            transform=ax.transAxes,
            fontsize=7,
            va="bottom",
            family="monospace",
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"},
        )
        _xy_axes(ax, ax.get_title())
        numbers[name] = {
            "degree_of_mobility": dom,
            "degree_of_steerability": dos,
            "icr_body_m": icr.tolist(),
            "inverse": dict(zip(drive.input_names, map(float, u), strict=False)),
            "roundtrip_error": float(np.max(np.abs(back - tw))),
        }
    axes[0, 0].legend(loc="upper right", fontsize=7)
    axes[1, 1].legend(loc="upper right", fontsize=7)
    fig.suptitle(
        "Drive zoo: one body twist per drive, its ICR and the inputs that produce it "
        "(wheel rates in rad/s, steering angles in rad)"
    )
    png = _save(fig, out_dir, "drive_zoo")
    return {"png": png, "numbers": numbers}


DEMOS = {
    "integration": demo_integration,
    "error_growth": demo_error_growth,
    "systematic": demo_systematic,
    "gyrodometry": demo_gyrodometry,
    "fusion": demo_fusion,
    "drive_zoo": demo_drive_zoo,
}


def run_demo(name: str, out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Run demo ``name`` (a key of :data:`DEMOS`); returns ``{"png", "numbers"}``."""
    if name not in DEMOS:
        raise ValueError(f"unknown demo '{name}'; known: {', '.join(sorted(DEMOS))}")
    return DEMOS[name](out_dir=out_dir, quick=quick, seed=seed)
