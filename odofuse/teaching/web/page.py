"""Build the ``odofuse teach`` page: one HTML file, inline CSS and JavaScript, no network.

The page's numbers come from ``model.js`` (the library's equations, one function per Python
function, named in its comments). This module adds what only the library knows, without
re-implementing it in JavaScript: the slider defaults (the simulator's
:class:`~odofuse.teaching.simulate.Scenario` geometry, the square's speeds) and the drive zoo
(:func:`drive_specs`: ``pinv(F)`` of each linear drive from its ``matrix()``, the wheel
positions of the steered drives, degrees of mobility, input names and units).
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np

from odofuse import __version__
from odofuse.errors import ConfigError

__all__ = ["PAGE_NAME", "page_config", "drive_specs", "build_page", "write_page"]

#: File name written by :func:`write_page`.
PAGE_NAME = "odofuse-teach.html"

#: Units of a drive input, by its ``input_kinds`` entry, for a body twist per second.
_UNITS = {"wheel": "rad/s", "steer": "rad", "steer_increment": "rad/s", "velocity": "m/s"}


def _slider(value, lo, hi, step, unit, label, log=False):
    return {
        "value": value,
        "min": lo,
        "max": hi,
        "step": step,
        "unit": unit,
        "label": label,
        "log": log,
    }


def page_config() -> dict:
    """Panel defaults and slider ranges (JSON-serialisable); the defaults are the library's.

    Error growth and fusion: the simulator's default differential robot
    (``Scenario().geometry``); UMBmark: that robot on Borenstein's 4 m square at the square
    path's default speed and turn rate, ``dt = 0.05`` s as ``odofuse calibrate umbmark``.
    """
    from odofuse.teaching.simulate import Scenario

    geom = dict(Scenario().geometry)
    r, b = float(geom["wheel_radius"]), float(geom["track_width"])
    growth = {
        "path": {"value": "straight", "options": ["straight", "circle", "square", "figure_eight"]},
        "integrator": {"value": "rk2", "options": ["euler", "rk2", "exact"]},
        "k_r": _slider(1e-6, 1e-7, 1e-2, 0.01, "m²/m", "k_r (right wheel)", log=True),
        "k_l": _slider(1e-6, 1e-7, 1e-2, 0.01, "m²/m", "k_l (left wheel)", log=True),
        "wheel_radius": _slider(r, 0.02, 0.2, 0.001, "m", "wheel radius r"),
        "track_width": _slider(b, 0.1, 1.0, 0.001, "m", "track width b"),
        "E_d": _slider(1.0, 0.98, 1.02, 0.0005, "", "E_d = D_R / D_L (true)"),
        "E_b": _slider(1.0, 0.95, 1.05, 0.001, "", "E_b = b_true / b (true)"),
        "step": _slider(0.05, 0.005, 0.5, 0.005, "m", "step length Δs"),
        "samples": _slider(500, 50, 2000, 50, "", "Monte Carlo samples"),
        "seed": 1,
        # path sizes (m) and the in-place turn per step: turn_rate = 2 rad per metre of step
        "straight_length": 5.0,
        "circle_radius": 1.0,
        "square_side": 4.0,
        "eight_radius": 1.0,
        "turn_per_step_per_m": 2.0,
        "checkpoints": 5,
    }
    umbmark = {
        "geometry": {"wheel_radius": r, "track_width": b},
        "E_d": _slider(1.002, 0.99, 1.01, 0.0005, "", "E_d (true)"),
        "E_b": _slider(1.01, 0.97, 1.03, 0.001, "", "E_b (true)"),
        "k": _slider(1e-7, 1e-9, 1e-5, 0.01, "m²/m", "k (both wheels)", log=True),
        "runs": _slider(5, 1, 20, 1, "", "runs per direction"),
        "side": _slider(4.0, 1.0, 8.0, 0.5, "m", "square side L"),
        "method": {"value": "exact", "options": ["exact", "linear"]},
        "speed": 0.3,
        "turn_rate": 0.8,
        "dt": 0.05,
        "seed": 2,
    }
    fusion = {
        "path": {
            "value": "figure_eight",
            "options": ["straight", "circle", "square", "figure_eight"],
        },
        "gyro": False,
        "gps": True,
        "gyro_sigma": _slider(0.005, 0.0005, 0.05, 0.0005, "rad/s", "gyro σ"),
        "gps_sigma": _slider(0.05, 0.01, 1.0, 0.01, "m", "GPS σ"),
        "gps_period": _slider(4.0, 1.0, 30.0, 1.0, "s", "GPS period"),
        "speed": 0.3,
        "seed": 3,
    }
    drives = {
        "omega": _slider(0.5, -1.0, 1.0, 0.05, "rad/s", "ω"),
        "vx": _slider(0.5, -1.0, 1.0, 0.05, "m/s", "v_x"),
        "vy": _slider(0.0, -1.0, 1.0, 0.05, "m/s", "v_y"),
        "zoo": drive_specs(),
    }
    return {
        "version": __version__,
        "growth": growth,
        "umbmark": umbmark,
        "fusion": fusion,
        "drives": drives,
    }


def _reaches(drive, twist) -> bool:
    try:
        u = np.asarray(drive.inverse(np.asarray(twist, dtype=float)), dtype=float)
    except ValueError:
        return False
    return bool(np.all(np.isfinite(u)))


def drive_specs() -> list[dict]:
    """The drive zoo of ``odofuse demo drive_zoo`` as data for the page's inverse kinematics.

    Linear drives (``twist = F u``) carry ``pinv(F)`` (their ``inverse``); steered drives carry
    their wheel contact points (body frame, m) and which input is a wheel's rolling rate
    (``speed / r``) or its steering angle, so the page computes the same ``inverse`` wheel by
    wheel (``base._steered_wheel_inverse``). ``holonomic``: ``v_y != 0`` is reachable;
    ``spot_turn``: a rotation without forward motion is.
    """
    from odofuse.drives import make_drive
    from odofuse.drives.base import _LinearDrive
    from odofuse.teaching.demos.drive_zoo import _AXES_MEET_AT_ICR, _ZOO, _wheel_layout

    out = []
    for name, geometry, twist in _ZOO:
        drive = make_drive(name, **geometry)
        kinds = tuple(drive.input_kinds)
        n = len(drive.input_names)
        spec: dict = {
            "name": name,
            "geometry": geometry,
            "twist": list(map(float, twist)),
            "inputs": list(drive.input_names),
            "units": [_UNITS[k] for k in kinds],
            "degree_of_mobility": int(drive.degree_of_mobility),
            "degree_of_steerability": int(getattr(drive, "degree_of_steerability", 0)),
            "holonomic": _reaches(drive, [0.0, 0.0, 0.1]),
            "spot_turn": _reaches(drive, [0.5, 0.0, 0.0]),
            "axes_meet": name in _AXES_MEET_AT_ICR,
        }
        layout = _wheel_layout(name, geometry, np.zeros(n))
        if isinstance(drive, _LinearDrive):
            spec["kind"] = "linear"
            spec["pinv"] = np.linalg.pinv(drive.matrix()).tolist()
            spec["draw"] = [[x, y, h, -1] for x, y, h in layout]
        else:
            spec["kind"] = "steered"
            wheels, inputs, draw = _steered(name, geometry, drive)
            spec["wheels"], spec["inputs_map"], spec["draw"] = wheels, inputs, draw
        out.append(spec)
    return out


def _steered(name: str, g: dict, drive):
    """Wheel contact points, the input map and the drawing list of a steered drive."""
    r = float(g["wheel_radius"])

    def rate(i):
        return {"type": "rate", "wheel": i, "radius": r}

    def steer(i):
        return {"type": "steer", "wheel": i}

    if name == "tricycle":
        wheels, inputs = [[g["wheelbase"], 0.0]], [rate(0), steer(0)]
        draw = [[0.0, 0.3 * g["wheelbase"], 0.0, -1], [0.0, -0.3 * g["wheelbase"], 0.0, -1]]
        draw.append([g["wheelbase"], 0.0, 0.0, 1])
    elif name == "bicycle":
        wheels, inputs = [[0.0, 0.0], [g["wheelbase"], 0.0]], [rate(0), steer(1)]
        draw = [[0.0, 0.0, 0.0, -1], [g["wheelbase"], 0.0, 0.0, 1]]
    elif name == "ackermann":
        d, b = g["wheelbase"], 0.5 * g["track_width"]
        wheels = [[d, b], [d, -b], [0.0, b], [0.0, -b]]
        inputs = [rate(0), rate(1), rate(2), rate(3), steer(0), steer(1)]
        draw = [[d, b, 0.0, 4], [d, -b, 0.0, 5], [0.0, b, 0.0, -1], [0.0, -b, 0.0, -1]]
    elif name == "swerve":
        wheels = [list(map(float, m)) for m in g["modules"]]
        k = len(wheels)
        inputs = [rate(i) for i in range(k)] + [steer(i) for i in range(k)]
        draw = [[x, y, 0.0, k + i] for i, (x, y) in enumerate(wheels)]
    elif name in ("car", "car_ackermann"):
        L, b = g["wheelbase"], 0.5 * g["track_width"]
        wheels = [[0.0, b], [0.0, -b]]
        inputs = [rate(0), rate(1)]
        draw = [[0.0, b, 0.0, -1], [0.0, -b, 0.0, -1]]
        if name == "car":
            wheels.append([L, 0.0])
            inputs.append(steer(2))
            draw.append([L, 0.0, 0.0, 2])
        else:
            bs = 0.5 * float(drive.steering_track_width)
            wheels += [[L, bs], [L, -bs]]
            inputs += [steer(2), steer(3)]
            draw += [[L, bs, 0.0, 2], [L, -bs, 0.0, 3]]
    else:  # pragma: no cover - a new steered drive in the zoo must be described here
        raise ConfigError(f"teach: no wheel description for steered drive '{name}'")
    return wheels, inputs, draw


def _asset(name: str) -> str:
    return resources.files("odofuse.teaching.web").joinpath(name).read_text(encoding="utf-8")


def _inline_json(obj) -> str:
    """JSON safe inside a ``<script>`` element (no ``</script>``, no HTML comment opener)."""
    text = json.dumps(obj, allow_nan=False, separators=(",", ":"))
    return text.replace("</", "<\\/").replace("<!--", "<\\!--")


def build_page(config: dict | None = None) -> str:
    """The page's HTML text: ``page.html`` with ``page.css``, ``model.js``, ``app.js`` and the
    configuration (default :func:`page_config`) inlined."""
    cfg = page_config() if config is None else config
    parts = {
        "/*@CSS@*/": _asset("page.css"),
        "/*@MODEL@*/": _asset("model.js"),
        "/*@APP@*/": _asset("app.js"),
        "/*@CONFIG@*/": _inline_json(cfg),
        "@VERSION@": str(cfg.get("version", __version__)),
    }
    html = _asset("page.html")
    for key, text in parts.items():
        if key not in html:
            raise ConfigError(f"teach: page.html lacks the placeholder {key}")
        if key.startswith("/*") and "</script" in text.lower() and key != "/*@CSS@*/":
            raise ConfigError(f"teach: {key} would close its <script> element")
        html = html.replace(key, text)
    return html


def write_page(folder=".") -> Path:
    """Write :data:`PAGE_NAME` into ``folder`` (created if missing); returns its path."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    path = out / PAGE_NAME
    path.write_text(build_page(), encoding="utf-8")
    return path
