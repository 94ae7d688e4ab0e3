"""Demos of the motion model: integration methods and error propagation.

``integration``: Euler vs Runge-Kutta 2 vs exact integration against the step size (Politecnico
slides ``003_73fced8ec7c15fe5.txt``). ``error_growth``: Siegwart's linearised covariance
propagation (``004_f4547100a083f338.txt``) against a Monte-Carlo cloud, with NEES; where the
banana parts from the ellipse for large heading noise.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse import se2
from odofuse.teaching.demos.figures import _COLORS, _ellipse, _figure, _save, _xy_axes, nees_bounds


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
    from odofuse.teaching.simulate import Scenario, WheelNoise, simulate

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
