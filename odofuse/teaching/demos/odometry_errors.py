"""Demos of odometry errors (``002_88fc37db58155723.txt``, Borenstein): UMBmark and gyrodometry.

``systematic``: systematic vs non-systematic errors on UMBmark squares and the UMBmark
correction (Borenstein & Feng); :func:`plot_umbmark` draws a UMBmark report (also used by
``odofuse calibrate umbmark``). ``gyrodometry``: Borenstein's gyrodometry over a bump and a slip
burst, with :func:`gyrodometry` itself.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from odofuse import se2
from odofuse.teaching.demos.figures import _COLORS, _figure, _save, _xy_axes


# ----------------------------------------------------------------------------- systematic
def _reduction_text(report) -> str:
    """``E_max,syst`` before -> after; the ratio only while the residual is measurable (a
    simulated robot without random error leaves micrometres: a ratio of 31101 says nothing)."""
    before, after = 100 * report.e_max_before, 100 * report.e_max_after
    text = f"E_max,syst {before:.3g} cm -> {after:.3g} cm"
    if after >= 0.01:  # 0.1 mm: below it the ratio measures the simulation's rounding
        text += f" (x{report.reduction:.0f} smaller)"
    return text


def plot_umbmark(report, side: float, path) -> str:
    """Return errors of a UMBmark report before and after the correction (two panels)."""
    from matplotlib.ticker import MaxNLocator

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
        ax.set_title(f"UMBmark {side:g} m square, {title}\nE_max,syst = {100 * emax:.3g} cm")
        ax.legend(loc="best", fontsize=8)
        # four ticks at most, in scientific notation when tiny: labels never overlap
        ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.yaxis.set_major_locator(MaxNLocator(4))
        ax.ticklabel_format(style="sci", scilimits=(-2, 3), useOffset=False)
    est = report.estimate
    fig.suptitle(f"Estimated E_d = {est.E_d:.5f}, E_b = {est.E_b:.5f}; {_reduction_text(report)}")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return str(out)


def demo_systematic(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Systematic vs non-systematic errors on UMBmark squares, and the UMBmark correction."""
    from dataclasses import replace

    from odofuse.teaching.simulate import Scenario, SystematicErrors, WheelNoise
    from odofuse.teaching.umbmark import calibrate_umbmark, systematic_return_error, umbmark_runs

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
    from odofuse.teaching.simulate import GyroSpec, Scenario, WheelNoise, simulate

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
