"""2-D pose-graph text files (the g2o / TORO formats ``gtsam.readG2o`` and ``gtsam.load2D`` read).

A pose graph has no time stamps, so pose ``k`` is stamped ``t = k`` seconds. The mapping:

``VERTEX_SE2 / VERTEX2 / VERTEX id x y theta``
    the vertex with the lowest id of the odometry chain gives ``SensorLog.initial_pose``; the
    other vertices are initial guesses, not truth, and are ignored.
``EDGE_SE2 / EDGE2 / ODOMETRY i j dx dy dtheta ...`` with ``|i - j| = 1``
    one ``odometry`` row at ``t = max(i, j)``: ``ds = sign(dx) hypot(dx, dy)`` and
    ``dtheta = wrap(dtheta)`` of the relative pose ``p_k^-1 p_{k+1}`` (an edge stored as
    ``k+1 -> k`` is inverted first). Other edges (loop closures) are skipped and counted as
    ``odometry.loop_closures_skipped``.
``LANDMARK i l lx ly ...``
    a ``landmarks`` row at ``t = i``: ``range = hypot(lx, ly)``, ``bearing = atan2(ly, lx)``
    (the landmark as a point in the robot frame, as ``gtsam.load2D`` reads it).
``BR i l bearing range ...``
    a ``landmarks`` row at ``t = i``.

The increments keep the forward distance and heading change (the lateral ``dy`` of a unicycle
arc is the chord offset ``ds sin(dtheta/2)``, second order), which is what the ``increments``
drive consumes; 3-D lines (``VERTEX_SE3``, ``EDGE_SE3``) raise an error.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse.errors import InputError
from odofuse.io.log import SensorLog, Stream
from odofuse.se2 import wrap

VERTEX_TAGS = ("VERTEX_SE2", "VERTEX2", "VERTEX")
EDGE_TAGS = ("EDGE_SE2", "EDGE2", "ODOMETRY")
KNOWN_TAGS = (
    VERTEX_TAGS
    + EDGE_TAGS
    + ("LANDMARK", "BR", "POINT2", "VERTEX_XY", "EQUIV", "EDGE_SE2_XY", "FIX")
)


def looks_like_gtsam_text(path: str | Path) -> bool:
    """True when the first non-empty line starts with a 2-D pose-graph tag."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                s = line.split()
                if s:
                    return s[0] in VERTEX_TAGS + EDGE_TAGS + ("LANDMARK", "BR")
    except OSError:
        return False
    return False


def _invert(d):
    c, s = math.cos(d[2]), math.sin(d[2])
    return (-(c * d[0] + s * d[1]), -(-s * d[0] + c * d[1]), -d[2])


def read_gtsam_text(path: str | Path) -> SensorLog:
    """Read a 2-D pose-graph text file into a ``SensorLog`` (see the module docstring).

    Raises
    ------
    InputError
        Naming the line: a short or non-numeric line, a 3-D tag, two odometry edges for one
        step, a missing step in the odometry chain, or no odometry at all.
    """
    name = str(path)
    vertices: dict[int, tuple] = {}
    steps: dict[int, tuple[tuple, int]] = {}
    obs: list[tuple[float, float, float, float]] = []
    skipped = 0
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, start=1):
            cells = line.split()
            if not cells or cells[0].startswith("#"):
                continue
            tag = cells[0]
            if "SE3" in tag or tag.startswith(("VERTEX3", "EDGE3")):
                raise InputError(
                    f"3-D pose-graph line '{tag}' (only 2-D graphs are supported)", name, lineno
                )
            if tag not in KNOWN_TAGS:
                raise InputError(f"unknown line type '{tag}'", name, lineno)
            need = {"LANDMARK": 5, "BR": 5}.get(tag, 5 if tag in VERTEX_TAGS else 6)
            if tag not in VERTEX_TAGS + EDGE_TAGS + ("LANDMARK", "BR"):
                continue
            if len(cells) < need:
                raise InputError(
                    f"{tag} needs at least {need - 1} values, got {len(cells) - 1}", name, lineno
                )
            try:
                nums = [float(c) for c in cells[1:need]]
            except ValueError:
                raise InputError(f"non-numeric value in {tag} line", name, lineno) from None
            if not all(math.isfinite(v) for v in nums):
                raise InputError(f"non-finite value in {tag} line", name, lineno)
            if tag in VERTEX_TAGS:
                vertices[int(nums[0])] = tuple(nums[1:4])
            elif tag in EDGE_TAGS:
                i, j, d = int(nums[0]), int(nums[1]), tuple(nums[2:5])
                if abs(i - j) != 1:
                    skipped += 1
                    continue
                k = min(i, j)
                if j < i:
                    d = _invert(d)
                if k in steps:
                    raise InputError(
                        f"second odometry edge between poses {k} and {k + 1} "
                        f"(first on line {steps[k][1]})",
                        name,
                        lineno,
                    )
                steps[k] = (d, lineno)
            elif tag == "LANDMARK":
                lx, ly = nums[2], nums[3]
                obs.append((nums[0], nums[1], math.hypot(lx, ly), math.atan2(ly, lx)))
            else:  # BR i l bearing range
                obs.append((nums[0], nums[1], nums[3], float(wrap(nums[2]))))
    if not steps:
        raise InputError(
            "no odometry edges (EDGE_SE2/EDGE2/ODOMETRY between consecutive poses)", name
        )
    ks = sorted(steps)
    missing = sorted(set(range(ks[0], ks[-1] + 1)) - set(ks))
    if missing:
        raise InputError(
            f"odometry chain has no edge between poses {missing[0]} and {missing[0] + 1}", name
        )
    d = np.array([steps[k][0] for k in ks])
    ds = np.where(d[:, 0] < 0, -1.0, 1.0) * np.hypot(d[:, 0], d[:, 1])
    dth = (d[:, 2] + math.pi) % (2 * math.pi) - math.pi
    t = np.asarray(ks, dtype=float) + 1.0
    streams = {
        "odometry": Stream("odometry", name, t, ("ds", "dtheta"), np.column_stack([ds, dth]))
    }
    if obs:
        o = np.array(sorted(obs, key=lambda r: (r[0], r[1])))
        streams["landmarks"] = Stream(
            "landmarks", name, o[:, 0], ("id", "range", "bearing"), o[:, 1:4]
        )
    initial = np.array(vertices[ks[0]], dtype=float) if ks[0] in vertices else None
    repairs = {"odometry.loop_closures_skipped": skipped} if skipped else {}
    return SensorLog(name, streams, {}, None, repairs, initial)
