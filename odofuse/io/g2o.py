"""g2o 2-D line types (``gtsam.readG2o`` for the SE(2) part; g2o's ``types_slam2d`` for the rest).

======================================================  ==========================================
line                                                    becomes (see :mod:`odofuse.io.posegraph`)
======================================================  ==========================================
``VERTEX_SE2 id x y theta``                             a pose; the first pose's gives the start
``EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33``   odometry step or loop closure; the six
                                                        entries are the *information* matrix by
                                                        rows (as ``readG2o``), inverted here
``VERTEX_XY id x y``                                    a landmark's initial guess: not read
``EDGE_SE2_XY i l x y I11 I12 I22``                     a ``landmarks`` sighting of the point
``LANDMARK2 i l x y I11 I12 I22``                       (robot frame), information inverted and
                                                        taken to range/bearing sigmas to first
                                                        order
``EDGE_BEARING_SE2_XY i l bearing I``                   a ``bearings`` row, ``sigma = I^-1/2``
``FIX id``                                              not read (the estimator anchors the first
                                                        pose), counted as ``posegraph.fix_ignored``
======================================================  ==========================================

``LANDMARK2`` is the layout of ``victoriaPark_reduced_1k.g2o`` and ``cityTrees_reduced_1k.g2o``
(no GTSAM reader takes it); it is read with g2o's convention (information), like ``EDGE_SE2``.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.errors import InputError
from odofuse.io.posegraph import (
    GraphBuilder,
    integer_id,
    numbers,
    point_to_range_bearing,
)
from odofuse.se2 import wrap


def _vertex(b: GraphBuilder, cells, row) -> None:
    v = numbers(cells, 4, cells[0], b.file, row)
    b.vertex(integer_id(v[0], cells[0], b.file, row), v[1:4])


def edge_noise(b: GraphBuilder, cells, row, first: int) -> list[float] | None:
    """The six noise entries starting at ``cells[first]``, ``None`` when the line has none."""
    extra = len(cells) - first
    if extra == 0:
        return None
    if extra < 6:
        raise InputError(f"{cells[0]} needs 0 or 6 noise entries, got {extra}", b.file, row)
    return numbers(cells[first - 1 :], 6, cells[0], b.file, row)


def _edge(b: GraphBuilder, cells, row) -> None:
    v = numbers(cells, 5, cells[0], b.file, row)
    i, j = (integer_id(x, cells[0], b.file, row) for x in v[:2])
    noise = edge_noise(b, cells, row, 6)
    b.edge(i, j, v[2:5], noise, True, row)


def _point(b: GraphBuilder, cells, row) -> None:
    v = numbers(cells, 7, cells[0], b.file, row)
    i, lm = (integer_id(x, cells[0], b.file, row) for x in v[:2])
    info = np.array([[v[4], v[5]], [v[5], v[6]]])
    if np.linalg.eigvalsh(info)[0] <= 0:
        raise InputError(f"{cells[0]} information matrix is not positive definite", b.file, row)
    r, brg, sr, sb = point_to_range_bearing(v[2], v[3], np.linalg.inv(info))
    if r == 0.0:
        raise InputError(f"{cells[0]}: landmark at the robot's origin (range 0)", b.file, row)
    b.sighting(i, lm, r, brg, sr, sb, row)


def _bearing(b: GraphBuilder, cells, row) -> None:
    v = numbers(cells, 4, cells[0], b.file, row)
    i, lm = (integer_id(x, cells[0], b.file, row) for x in v[:2])
    if v[3] <= 0:
        raise InputError(f"{cells[0]} information must be positive, got {v[3]!r}", b.file, row)
    b.bearing(i, lm, float(wrap(v[2])), 1.0 / math.sqrt(v[3]), row)


def _landmark_guess(b: GraphBuilder, cells, row) -> None:
    numbers(cells, 3, cells[0], b.file, row)  # checked, not used: an initial guess


def _fix(b: GraphBuilder, cells, row) -> None:
    numbers(cells, 1, cells[0], b.file, row)
    b.count("posegraph.fix_ignored")


PARSERS = {
    "VERTEX_SE2": _vertex,
    "EDGE_SE2": _edge,
    "VERTEX_XY": _landmark_guess,
    "EDGE_SE2_XY": _point,
    "LANDMARK2": _point,
    "EDGE_BEARING_SE2_XY": _bearing,
    "FIX": _fix,
}
REFUSED = {
    "EDGE_PRIOR_SE2": "pose priors are not read (give initial.pose in the config)",
    "EDGE_SE2_PRIOR": "pose priors are not read (give initial.pose in the config)",
    "PARAMS_SE2OFFSET": "sensor offsets are not read",
    "EDGE_SE2_OFFSET": "sensor offsets are not read",
    "EDGE_SE2_POINT_XY_CALIB": "calibration edges are not read",
}
