"""iSAM 2-D text line types (``victoria_park.txt``, the ``BR`` lines of ``example.graph``).

=============================================  ==================================================
line                                           becomes (see :mod:`odofuse.io.posegraph`)
=============================================  ==================================================
``ODOMETRY i j dx dy dtheta v1 .. v6``         odometry step or loop closure; a covariance, read
                                               as for TORO ``EDGE2`` (:mod:`odofuse.io.toro`),
                                               like ``gtsam.load2D``
``LANDMARK i l lx ly cxx cxy cyy``             a ``landmarks`` sighting of the point
                                               ``(lx, ly)`` (robot frame): ``range``, ``bearing``;
                                               with ``cxx == cyy`` the sigmas are load2D's
                                               (``sigma_range = sqrt(cxx)``,
                                               ``sigma_bearing = sqrt(cxx / 10)``: the covariance
                                               taken to describe a point 10 m away), else the
                                               first-order conversion of the point covariance
``BR i l bearing range sigma_b sigma_r``       a ``landmarks`` sighting as written
=============================================  ==================================================

Poses and landmarks share one id space: the odometry chain is the pose ids in increasing order,
so the poses of Victoria Park, which skip the ids of its trees, form one chain.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.errors import InputError
from odofuse.io.posegraph import GraphBuilder, integer_id, numbers, point_to_range_bearing
from odofuse.io.toro import covariance_edge
from odofuse.se2 import wrap


def _landmark(b: GraphBuilder, cells, row) -> None:
    v = numbers(cells, 7, cells[0], b.file, row)
    i, lm = (integer_id(x, cells[0], b.file, row) for x in v[:2])
    lx, ly, cxx, cxy, cyy = v[2:7]
    cov = np.array([[cxx, cxy], [cxy, cyy]])
    if np.linalg.eigvalsh(cov)[0] <= 0:
        raise InputError("LANDMARK covariance is not positive definite", b.file, row)
    r, brg, sr, sb = point_to_range_bearing(lx, ly, cov)
    if r == 0.0:
        raise InputError("LANDMARK at the robot's origin (range 0)", b.file, row)
    if abs(cxx - cyy) < 1e-4:  # gtsam.load2D's reading of an isotropic sighting
        sr, sb = math.sqrt(cxx), math.sqrt(cxx / 10.0)
    b.sighting(i, lm, r, brg, sr, sb, row)


def _br(b: GraphBuilder, cells, row) -> None:
    v = numbers(cells, 6, cells[0], b.file, row)
    i, lm = (integer_id(x, cells[0], b.file, row) for x in v[:2])
    bearing, rng, sb, sr = v[2:6]
    if rng < 0 or sb <= 0 or sr <= 0:
        raise InputError("BR needs range >= 0 and positive sigmas", b.file, row)
    b.sighting(i, lm, rng, float(wrap(bearing)), sr, sb, row)


PARSERS = {"ODOMETRY": covariance_edge, "LANDMARK": _landmark, "BR": _br}
REFUSED: dict[str, str] = {}
