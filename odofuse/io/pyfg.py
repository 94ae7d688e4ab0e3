"""PyFactorGraph text files (``.pyfg``, MIT Marine Robotics Group; ``goats_15/16.pyfg``).

Variables are named: a letter and an index for poses (``A0``, ``A1`` ...; one robot), ``L`` and
an index for landmarks (``L0`` ...). Noise entries are covariances, upper triangle by rows
(``xx xy xt yy yt tt``, as ``py_factor_graph`` writes them).

=====================================================  ==========================================
line                                                   becomes
=====================================================  ==========================================
``VERTEX_SE2 t A<k> x y theta``                        pose ``k``; the first one's pose is the
                                                       start. In the GOATS files these equal the
                                                       composed odometry (to 1e-9 m): initial
                                                       guesses, not ground truth
``VERTEX_XY L<l> x y``                                 known beacon ``l``: ``SensorLog.landmarks``
                                                       (``map.csv``)
``EDGE_SE2 t A<i> A<j> dx dy dtheta c1 .. c6``         odometry step or loop closure
                                                       (:mod:`odofuse.io.posegraph`)
``EDGE_SE2_XY t A<i> L<l> x y cxx cxy cyy``            a ``landmarks`` sighting, first-order
                                                       range/bearing sigmas
``EDGE_RANGE t A<i> L<l> range variance``              a ``ranges`` row, ``sigma = sqrt(variance)``
=====================================================  ==========================================

Poses are stamped with the file's times when those increase along the chain; the GOATS files
stamp every line ``0.0``, so there pose ``k`` gets ``t = k`` s. Priors, inter-robot ranges,
several robots and 3-D lines are refused by name.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse.errors import InputError
from odofuse.io.log import SensorLog
from odofuse.io.posegraph import GraphBuilder, numbers, point_to_range_bearing, read_lines

REFUSED = {
    "VERTEX_SE2:PRIOR": "pose priors are not read (give initial.pose in the config)",
    "VERTEX_XY:PRIOR": "landmark priors are not read",
}


class _PyfgBuilder(GraphBuilder):
    def __init__(self, file: str) -> None:
        super().__init__(file)
        self.robot: str | None = None
        self.stamps: dict[int, float] = {}

    def pose(self, name: str, row: int) -> int:
        if len(name) < 2 or not name[0].isalpha() or name[0] == "L" or not name[1:].isdigit():
            raise InputError(
                f"'{name}' is not a pose name (a letter other than L, then digits)", self.file, row
            )
        if self.robot is None:
            self.robot = name[0]
        elif name[0] != self.robot:
            raise InputError(
                f"pose '{name}' of a second robot ('{self.robot}' first): multi-robot graphs "
                "are not supported",
                self.file,
                row,
            )
        return int(name[1:])

    def landmark(self, name: str, row: int) -> int:
        if len(name) < 2 or name[0] != "L" or not name[1:].isdigit():
            if name[:1].isalpha() and name[1:].isdigit():
                raise InputError(
                    f"range between two poses ('{name}'): not supported", self.file, row
                )
            raise InputError(f"'{name}' is not a landmark name (L then digits)", self.file, row)
        return int(name[1:])


def _floats(b: _PyfgBuilder, cells, first: int, count: int, row: int) -> list[float]:
    return numbers([cells[0]] + cells[first:], count, cells[0], b.file, row)


def _vertex_se2(b: _PyfgBuilder, cells, row) -> None:
    if len(cells) < 6:
        raise InputError(f"VERTEX_SE2 needs 5 values, got {len(cells) - 1}", b.file, row)
    (t,) = _floats(b, cells, 1, 1, row)
    k = b.pose(cells[2], row)
    b.vertex(k, _floats(b, cells, 3, 3, row))
    b.stamps[k] = t


def _vertex_xy(b: _PyfgBuilder, cells, row) -> None:
    if len(cells) < 4:
        raise InputError(f"VERTEX_XY needs 3 values, got {len(cells) - 1}", b.file, row)
    lm = b.landmark(cells[1], row)
    if lm in b.landmark_map:
        raise InputError(f"landmark L{lm} defined twice", b.file, row)
    b.landmark_map[lm] = np.array(_floats(b, cells, 2, 2, row))


def _edge_se2(b: _PyfgBuilder, cells, row) -> None:
    if len(cells) < 13:
        raise InputError(f"EDGE_SE2 needs 12 values, got {len(cells) - 1}", b.file, row)
    i, j = b.pose(cells[2], row), b.pose(cells[3], row)
    v = _floats(b, cells, 4, 9, row)
    b.edge(i, j, v[:3], v[3:9], False, row)


def _edge_se2_xy(b: _PyfgBuilder, cells, row) -> None:
    if len(cells) < 9:
        raise InputError(f"EDGE_SE2_XY needs 8 values, got {len(cells) - 1}", b.file, row)
    i, lm = b.pose(cells[2], row), b.landmark(cells[3], row)
    lx, ly, cxx, cxy, cyy = _floats(b, cells, 4, 5, row)
    cov = np.array([[cxx, cxy], [cxy, cyy]])
    if np.linalg.eigvalsh(cov)[0] <= 0:
        raise InputError("EDGE_SE2_XY covariance is not positive definite", b.file, row)
    r, brg, sr, sb = point_to_range_bearing(lx, ly, cov)
    if r == 0.0:
        raise InputError("EDGE_SE2_XY: landmark at the robot's origin (range 0)", b.file, row)
    b.sighting(i, lm, r, brg, sr, sb, row)


def _edge_range(b: _PyfgBuilder, cells, row) -> None:
    if len(cells) < 6:
        raise InputError(f"EDGE_RANGE needs 5 values, got {len(cells) - 1}", b.file, row)
    i, lm = b.pose(cells[2], row), b.landmark(cells[3], row)
    rng, var = _floats(b, cells, 4, 2, row)
    if rng < 0 or var <= 0:
        raise InputError("EDGE_RANGE needs range >= 0 and a positive variance", b.file, row)
    b.range(i, lm, rng, math.sqrt(var), row)


PARSERS = {
    "VERTEX_SE2": _vertex_se2,
    "VERTEX_XY": _vertex_xy,
    "EDGE_SE2": _edge_se2,
    "EDGE_SE2_XY": _edge_se2_xy,
    "EDGE_RANGE": _edge_range,
}


def looks_like_pyfg(path: str | Path) -> bool:
    """``.pyfg`` files, or a first line in pyfg's named-variable form (``VERTEX_XY L0 ...``)."""
    from odofuse.io.gtsam_text import first_line

    if Path(path).suffix.lower() == ".pyfg":
        return True
    cells = first_line(path)
    if not cells or cells[0] not in PARSERS or len(cells) < 3:
        return False
    name = cells[1] if cells[0] == "VERTEX_XY" else cells[2]
    return name[:1].isalpha()


def read_pyfg(path: str | Path) -> SensorLog:
    """Read a 2-D ``.pyfg`` file into a ``SensorLog`` (see the module docstring)."""
    b = read_lines(path, PARSERS, REFUSED, _PyfgBuilder(str(path)))
    ids = sorted(b.pose_ids)
    stamps = [b.stamps.get(k) for k in ids]
    if all(s is not None for s in stamps) and np.all(np.diff(stamps) > 0):
        b.times = dict(zip(ids, stamps, strict=True))
    for stream in ("ranges", "landmarks"):
        for r in b.observations[stream]:
            if b.landmark_map and r[1] not in b.landmark_map:
                raise InputError(f"landmark L{r[1]} has no VERTEX_XY line", b.file, r[-1])
    return b.build()
