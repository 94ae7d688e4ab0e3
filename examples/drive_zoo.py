"""The drive zoo: forward and inverse kinematics, ICR and degree of mobility of every drive.

The story
---------
Every wheeled robot in the course material maps wheel inputs to a body twist
``[omega, v_x, v_y]`` (Modern Robotics 13.4, the Politecnico slides, Siegwart ch. 3). The
instantaneous centre of rotation (ICR) is where all wheel axes meet; the degree of mobility
says how many twist components the wheels can choose freely: 3 for omnidirectional robots,
2 for a differential drive (no sideways motion), 1 for car-like drives (the steering must be
set first).

For each drive this script asks for the inputs that produce one twist (inverse kinematics),
checks that forward kinematics gives the twist back, prints the ICR, and plans a
turn-drive-turn manoeuvre (Politecnico slides) to a goal pose. The picture comes from
:func:`odofuse.teaching.demos.demo_drive_zoo`.

Run ``python examples/drive_zoo.py --out zoo-out`` (``--quick``: coarser picture).
"""

from __future__ import annotations

import argparse

import numpy as np

from odofuse.drives import make_drive, turn_drive_turn
from odofuse.teaching.demos import demo_drive_zoo

ROBOTS = {
    "differential": {"wheel_radius": 0.05, "track_width": 0.4},
    "skid_steer": {"wheel_radius": 0.1, "track_width": 0.5},
    "synchro": {"wheel_radius": 0.05},
    "tricycle": {"wheel_radius": 0.1, "wheelbase": 0.6},
    "bicycle": {"wheel_radius": 0.3, "wheelbase": 1.0},
    "ackermann": {"wheel_radius": 0.3, "wheelbase": 1.0, "track_width": 0.6},
    "omni3": {"wheel_radius": 0.05, "wheel_distance": 0.2},
    "mecanum4": {"wheel_radius": 0.05, "half_length": 0.2, "half_width": 0.15},
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="zoo-out", help="output folder")
    parser.add_argument("--quick", action="store_true", help="coarser picture")
    args = parser.parse_args(argv)
    twist = np.array([0.5, 0.5, 0.0])  # omega [rad/s], v_x, v_y [m/s]
    print(f"twist {twist.tolist()} -> inputs (rad/s for wheels, rad for steering)")
    for name, geometry in ROBOTS.items():
        drive = make_drive(name, **geometry)
        u = drive.inverse(twist)
        back = drive.twist(u)
        icr = drive.icr(twist)
        inputs = ", ".join(f"{n}={v:+.2f}" for n, v in zip(drive.input_names, u, strict=True))
        print(
            f"{name:12s} dm={drive.degree_of_mobility} ICR=({icr[0]:+.2f}, {icr[1]:+.2f}) m  "
            f"{inputs}  |twist error|={np.max(np.abs(back - twist)):.1e}"
        )
    plan = turn_drive_turn([0.0, 0.0, 0.0], [2.0, 2.0, np.pi])
    print(
        "turn-drive-turn from (0, 0, 0) to (2, 2, pi): "
        f"turn {plan[0, 0]:+.3f} rad, drive {plan[1, 1]:.3f} m, turn {plan[2, 0]:+.3f} rad"
    )
    result = demo_drive_zoo(args.out, quick=args.quick)
    print(f"picture: {result['png']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
