"""TORO / ``.graph`` 2-D line types, read as ``gtsam.load2D`` reads them.

=================================================  ===============================================
line                                               becomes (see :mod:`odofuse.io.posegraph`)
=================================================  ===============================================
``VERTEX2 / VERTEX id x y theta``                  a pose; the first pose's gives the start
``EDGE2 / EDGE i j dx dy dtheta v1 .. v6``         odometry step or loop closure; the six entries
                                                   are a *covariance* whose layout comes from the
                                                   zero pattern as in ``load2D`` (AUTO):
                                                   ``a 0 b c 0 0`` TORO order (xx xy yy tt xt yt),
                                                   ``a 0 0 b 0 c`` by rows (xx xy xt yy yt tt);
                                                   another pattern is an error (load2D refuses it)
``EQUIV i j``                                      not read, as ``load2D`` does not; counted as
                                                   ``posegraph.equiv_ignored``
=================================================  ===============================================

The TORO documentation calls these entries information; GTSAM's ``load2D`` (whose optimum is the
reference for the pose graphs in its wheel) reads them as a covariance, and so does odofuse.
The multi-hypothesis layout of ``T1_city10000_04.txt`` (``EDGE2 from 1 to ambiguous n`` then
``n`` alternative ``dx dy dtheta``, no noise; GTSAM's ``HybridCity10000`` example) is refused by
name: odofuse has no estimator for discrete alternatives.
"""

from __future__ import annotations

from odofuse.errors import InputError
from odofuse.io.g2o import edge_noise
from odofuse.io.posegraph import GraphBuilder, integer_id, load2d_layout, numbers, rows_order


def _vertex(b: GraphBuilder, cells, row) -> None:
    v = numbers(cells, 4, cells[0], b.file, row)
    b.vertex(integer_id(v[0], cells[0], b.file, row), v[1:4])


def _multi_hypothesis(cells) -> bool:
    if len(cells) < 9 or cells[2] != "1" or cells[4] not in ("0", "1"):
        return False
    try:
        n = int(cells[5])
    except ValueError:
        return False
    return n >= 1 and len(cells) == 6 + 3 * n


def covariance_edge(b: GraphBuilder, cells, row) -> None:
    """An edge whose noise entries are a covariance in load2D's AUTO layouts (also iSAM)."""
    if cells[0] == "EDGE2" and _multi_hypothesis(cells):
        raise InputError(
            "EDGE2 in the multi-hypothesis layout of GTSAM's City10000 dataset "
            "(from, 1, to, ambiguous, n alternatives) is not supported: odofuse has no "
            "estimator for discrete measurement alternatives",
            b.file,
            row,
        )
    v = numbers(cells, 5, cells[0], b.file, row)
    i, j = (integer_id(x, cells[0], b.file, row) for x in v[:2])
    noise = edge_noise(b, cells, row, 6)
    if noise is not None:
        layout = load2d_layout(noise)
        if not layout:
            raise InputError(
                f"{cells[0]} noise entries {' '.join(cells[6:12])} match neither covariance "
                "layout gtsam.load2D recognises (a 0 b c 0 0 or a 0 0 b 0 c)",
                b.file,
                row,
            )
        noise = rows_order(noise, layout)
    b.edge(i, j, v[2:5], noise, False, row)


def _equiv(b: GraphBuilder, cells, row) -> None:
    numbers(cells, 2, cells[0], b.file, row)
    b.count("posegraph.equiv_ignored")


PARSERS = {
    "VERTEX2": _vertex,
    "VERTEX": _vertex,
    "EDGE2": covariance_edge,
    "EDGE": covariance_edge,
    "EQUIV": _equiv,
}
REFUSED: dict[str, str] = {}
