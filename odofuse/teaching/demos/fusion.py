"""Demo ``fusion``: dead reckoning vs EKF vs smoother on a simulated run through a GPS outage."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse.teaching.demos.figures import _COLORS, _figure, _save, _xy_axes


def demo_fusion(out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Dead reckoning vs EKF vs smoother through a GPS outage (simulated figure eight)."""
    import tempfile

    from odofuse.config import load_config
    from odofuse.errors import OdofuseError
    from odofuse.estimators import get_estimator
    from odofuse.io.loader import load_log_for
    from odofuse.teaching.simulate import (
        GpsSpec,
        GyroSpec,
        Scenario,
        SystematicErrors,
        WheelNoise,
        simulate,
        write_log,
    )
    from odofuse.trajectory import interpolate_poses

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
    length = float(np.sum(np.hypot(*np.diff(sim.truth[:, :2], axis=0).T)))
    dataset = f"simulated figure eight ({length:.0f} m, seed {seed})"
    rmse = ", ".join(
        f"{name.replace('_', ' ')} {numbers[name]['rmse_m']:.2f} m" for name in results
    )
    _xy_axes(ax, f"{dataset}: wheels + gyro + GPS\nATE RMSE: {rmse}")
    ax.legend(loc="best", fontsize=8)
    ax2.axvspan(*outage, color="gold", alpha=0.3, label="GPS outage")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("position error [m]")
    ax2.set_yscale("log")
    ax2.set_ylim(bottom=1e-2)
    ax2.set_title(f"Position error against ground truth (seed {seed})\nATE RMSE: {rmse}")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(loc="best", fontsize=8)
    png = _save(fig, out_dir, "fusion")
    return {"png": png, "numbers": numbers}
