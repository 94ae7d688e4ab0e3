"""Demo ``drive_zoo``: each drive's path under one twist, its wheels, ICR and inverse kinematics.

Degree of mobility and steerability per drive; for car-like and differential drives the wheel
axes are drawn to show they meet at the ICR.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse import se2
from odofuse.teaching.demos.figures import _figure, _robot_marker, _save, _xy_axes

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
            f"{name}: δm = {dom}, δs = {dos}\n"
            f"twist ω = {tw[0]:g} rad/s, vx = {tw[1]:g} m/s, vy = {tw[2]:g} m/s",
            fontsize=10,
        )
        units = {"wheel": "rad/s", "steer": "rad", "steer_increment": "rad/s"}
        text = "\n".join(
            f"{k} = {v:+.2f} {units.get(kind, '')}"
            for k, v, kind in zip(drive.input_names, u, drive.input_kinds, strict=True)
        )
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
