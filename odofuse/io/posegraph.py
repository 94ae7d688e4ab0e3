"""What the 2-D pose-graph readers share: line splitting, noise matrices, and the odometry chain.

The format modules (:mod:`odofuse.io.g2o`, :mod:`odofuse.io.toro`, :mod:`odofuse.io.isam_text`,
:mod:`odofuse.io.pyfg`) turn each line into calls on a :class:`GraphBuilder`;
:meth:`GraphBuilder.build` turns what was collected into a :class:`~odofuse.io.log.SensorLog`:

``odometry`` (``t, ds, dtheta, dx, dy, cov_xx .. cov_tt``)
    one row per step of the odometry chain, stamped at the later pose: the relative pose
    ``p_k^-1 p_{k+1}`` (an edge stored ``k+1 -> k`` is inverted, its covariance carried over
    by the adjoint), ``ds = sign(dx) hypot(dx, dy)`` for the ``increments`` drive.
``loop_closures`` (``t, t_from, t_to, dx, dy, dtheta, cov_xx .. cov_tt``)
    every other relative-pose edge, as stored (``p_from^-1 p_to``, ``dtheta`` wrapped to
    [-pi, pi)), ``t = max(t_from, t_to)``, rows in file order within one ``t``.
``landmarks`` (``t, id, range, bearing, sigma_range, sigma_bearing``), ``bearings``
(``t, id, bearing, sigma``), ``ranges`` (``t, id, range, sigma``)
    observations from a pose, stamped at that pose.

The odometry chain is the pose ids in increasing order, whatever ids landmarks use: ids are one
space in the iSAM format, so Victoria Park's poses skip the ids of its trees and the step
``4 -> 6`` is odometry. A pose is stamped ``t = id`` unless the format has times (pyfg); such
made-up stamps are listed in ``SensorLog.invented_times`` (every stream of the log), so that
no plausibility check takes ``1 s`` per pose for a measured time.

Covariances are of the edge's ``(dx, dy, dtheta)`` in GTSAM's ``Pose2`` tangent space (the
frame of the ``to`` pose; ``BetweenFactorPose2`` uses the same), upper triangle, SI units.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from odofuse.errors import InputError
from odofuse.io.log import SensorLog, Stream

COV_COLUMNS = ("cov_xx", "cov_xy", "cov_xt", "cov_yy", "cov_yt", "cov_tt")
ODOMETRY_COLUMNS = ("ds", "dtheta", "dx", "dy") + COV_COLUMNS
LOOP_COLUMNS = ("t_from", "t_to", "dx", "dy", "dtheta") + COV_COLUMNS

#: Leading tags of 3-D graph lines: refused by name in every 2-D reader.
THREE_D_PREFIXES = ("VERTEX3", "EDGE3", "VERTEX_SE3", "EDGE_SE3", "VERTEX_TRACKXYZ", "VERTEX_XYZ")

_TRIU = (0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)
_NO_NOISE = [math.nan] * 6


def numbers(cells: list[str], count: int, tag: str, file: str, row: int) -> list[float]:
    """The ``count`` numbers after the tag (``cells[1:count+1]``), finite, or an InputError."""
    if len(cells) - 1 < count:
        raise InputError(f"{tag} needs at least {count} values, got {len(cells) - 1}", file, row)
    try:
        out = [float(c) for c in cells[1 : count + 1]]
    except ValueError:
        raise InputError(f"non-numeric value in {tag} line", file, row) from None
    if not all(math.isfinite(v) for v in out):
        raise InputError(f"non-finite value in {tag} line", file, row)
    return out


def integer_id(value: float, tag: str, file: str, row: int) -> int:
    if value != round(value) or value < 0:
        raise InputError(f"{tag}: id {value!r} is not a non-negative integer", file, row)
    return int(value)


def rows_order(v, layout: str = "g2o") -> list[float]:
    """Six symmetric-matrix entries in the by-rows order ``m11 m12 m13 m22 m23 m33``.

    ``layout="g2o"``: already by rows (g2o, iSAM, pyfg); ``layout="toro"``:
    ``m_ff m_fs m_ss m_rr m_fr m_sr`` (TORO; GTSAM's ``NoiseFormatTORO``/``GRAPH``).
    """
    a = list(v)
    return [a[0], a[1], a[4], a[2], a[5], a[3]] if layout == "toro" else a


def symmetric(entries: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` symmetric matrices from ``(N, 6)`` by-rows upper-triangle entries."""
    e = np.asarray(entries, dtype=float).reshape(-1, 6)
    m = np.empty((len(e), 3, 3))
    for k, (r, c) in enumerate(_TRIU):
        m[:, r, c] = m[:, c, r] = e[:, k]
    return m


def load2d_layout(v) -> str:
    """The layout ``gtsam.load2D`` (``NoiseFormatAUTO``) infers from the zero pattern of 6 entries.

    ``"toro"`` for ``a 0 b c 0 0`` (GTSAM's ``NoiseFormatGRAPH``), ``"g2o"`` for ``a 0 0 b 0 c``
    (``NoiseFormatCOV``); both are read as covariances. Anything else: ``""`` (load2D refuses).
    """
    nz = [x != 0.0 for x in v]
    if nz == [True, False, True, True, False, False]:
        return "toro"
    if nz == [True, False, False, True, False, True]:
        return "g2o"
    return ""


def adjoint(d) -> np.ndarray:
    """Adjoint of the SE(2) pose ``d = (x, y, theta)`` on ``[x, y, theta]`` tangent vectors."""
    c, s = math.cos(d[2]), math.sin(d[2])
    return np.array([[c, -s, d[1]], [s, c, -d[0]], [0.0, 0.0, 1.0]])


def invert(d, cov: np.ndarray) -> tuple[tuple[float, float, float], np.ndarray]:
    """``d^-1`` and its covariance: ``T Exp(xi)`` inverted is ``T^-1 Exp(-Ad_T xi)``."""
    c, s = math.cos(d[2]), math.sin(d[2])
    inv = (-(c * d[0] + s * d[1]), -(-s * d[0] + c * d[1]), -d[2])
    a = adjoint(d)
    return inv, a @ cov @ a.T


def point_to_range_bearing(
    lx: float, ly: float, cov: np.ndarray
) -> tuple[float, float, float, float]:
    """Range, bearing and their sigmas of a point ``(lx, ly)`` (robot frame) with 2x2 ``cov``.

    First order: ``var_r = u^T C u``, ``var_b = v^T C v / r^2`` with ``u`` the unit vector to the
    point and ``v`` its normal; the range-bearing correlation (zero for an isotropic ``C``) is
    dropped.
    """
    r = math.hypot(lx, ly)
    b = math.atan2(ly, lx)
    u = np.array([math.cos(b), math.sin(b)])
    v = np.array([-u[1], u[0]])
    sr = math.sqrt(max(float(u @ cov @ u), 0.0))
    sb = math.sqrt(max(float(v @ cov @ v), 0.0)) / r if r > 0 else math.inf
    return r, b, sr, sb


class GraphBuilder:
    """Collects the lines of one file; :meth:`build` makes the SensorLog (module docstring)."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.vertices: dict[int, tuple[float, float, float]] = {}
        self.pose_ids: set[int] = set()
        self.times: dict[int, float] = {}
        self.landmark_map: dict[int, np.ndarray] = {}
        self.groundtruth: list[tuple[int, float, float, float]] = []
        self.repairs: dict[str, int] = {}
        self._edges: list[tuple[int, int, float, float, float, int]] = []
        self._noise: list = []
        self._noise_is_info: list[bool] = []
        self.observations: dict[str, list[tuple]] = {"landmarks": [], "bearings": [], "ranges": []}

    # -- what the format modules call ------------------------------------------------------
    def vertex(self, i: int, pose) -> None:
        self.vertices[i] = tuple(pose)
        self.pose_ids.add(i)

    def edge(self, i: int, j: int, d, noise, information: bool, row: int) -> None:
        """A relative-pose edge ``p_i^-1 p_j = d``.

        ``noise``: six covariance (or, with ``information``, information) entries by rows
        (:func:`rows_order`), or ``None`` when the line has none (NaN covariance columns).
        """
        if i == j:
            raise InputError(f"edge from pose {i} to itself", self.file, row)
        self._edges.append((i, j, float(d[0]), float(d[1]), float(d[2]), row))
        self._noise.append(_NO_NOISE if noise is None else noise)
        self._noise_is_info.append(information)
        self.pose_ids.update((i, j))

    def sighting(self, pose: int, landmark: int, rng, bearing, sigma_r, sigma_b, row: int):
        self.observations["landmarks"].append((pose, landmark, rng, bearing, sigma_r, sigma_b, row))

    def bearing(self, pose: int, landmark: int, bearing: float, sigma: float, row: int):
        self.observations["bearings"].append((pose, landmark, bearing, sigma, row))

    def range(self, pose: int, landmark: int, rng: float, sigma: float, row: int):
        self.observations["ranges"].append((pose, landmark, rng, sigma, row))

    def count(self, key: str, n: int = 1) -> None:
        self.repairs[key] = self.repairs.get(key, 0) + n

    # -- assembly --------------------------------------------------------------------------
    def _covariances(self) -> np.ndarray:
        if not self._noise:
            return np.empty((0, 3, 3))
        m = symmetric(self._noise)
        info = np.asarray(self._noise_is_info)
        given = np.isfinite(m).all(axis=(1, 2))  # a line without noise entries: NaN
        eig = np.ones((len(m), 3))
        if given.any():
            eig[given] = np.linalg.eigvalsh(m[given])
        bad = np.flatnonzero(eig[:, 0] <= 0.0)
        if bad.size:
            k = int(bad[0])
            what = "information" if info[k] else "covariance"
            raise InputError(
                f"edge {what} matrix is not positive definite", self.file, self._edges[k][5]
            )
        cov = m.copy()
        info &= given
        if info.any():
            cov[info] = np.linalg.inv(m[info])
        return cov

    def _time(self, pose: int) -> float:
        return self.times.get(pose, float(pose))

    def build(self) -> SensorLog:
        """Chain, loop closures and observation streams (module docstring)."""
        name = self.file
        if not self._edges:
            raise InputError("no relative-pose edges (no odometry chain)", name)
        cov = self._covariances()
        order = sorted(self.pose_ids)
        nxt = dict(zip(order[:-1], order[1:], strict=True))
        steps: dict[int, tuple[tuple, np.ndarray, int]] = {}
        loops = []
        for k, (i, j, dx, dy, dth, row) in enumerate(self._edges):
            a, b = min(i, j), max(i, j)
            if nxt.get(a) != b:
                loops.append((i, j, dx, dy, dth, cov[k]))
                continue
            if a in steps:
                raise InputError(
                    f"second odometry edge between poses {a} and {b} (first on line {steps[a][2]})",
                    name,
                    row,
                )
            d, c = (dx, dy, dth), cov[k]
            if i > j:
                d, c = invert(d, c)
            steps[a] = (d, c, row)
        missing = [a for a in order[:-1] if a not in steps]
        if missing:
            a = missing[0]
            raise InputError(f"odometry chain has no edge between poses {a} and {nxt[a]}", name)
        ks = order[:-1]
        d = np.array([steps[a][0] for a in ks])
        c = np.stack([steps[a][1] for a in ks])
        triu = np.column_stack([c[:, r, q] for r, q in _TRIU])
        ds = np.where(d[:, 0] < 0, -1.0, 1.0) * np.hypot(d[:, 0], d[:, 1])
        dth = (d[:, 2] + math.pi) % (2 * math.pi) - math.pi
        t = np.array([self._time(nxt[a]) for a in ks])
        if np.any(np.diff(np.concatenate([[self._time(order[0])], t])) <= 0):
            raise InputError("pose times do not increase along the odometry chain", name)
        streams = {
            "odometry": Stream(
                "odometry", name, t, ODOMETRY_COLUMNS, np.column_stack([ds, dth, d[:, :2], triu])
            )
        }
        if loops:
            lt = np.array(
                [[self._time(i), self._time(j), dx, dy, dz] for i, j, dx, dy, dz, _ in loops]
            )
            lt[:, 4] = (lt[:, 4] + math.pi) % (2 * math.pi) - math.pi
            lc = np.stack([x[5] for x in loops])
            values = np.column_stack([lt, np.column_stack([lc[:, r, q] for r, q in _TRIU])])
            tt = np.maximum(lt[:, 0], lt[:, 1])
            o = np.argsort(tt, kind="stable")
            streams["loop_closures"] = Stream("loop_closures", name, tt[o], LOOP_COLUMNS, values[o])
        cols = {
            "landmarks": ("id", "range", "bearing", "sigma_range", "sigma_bearing"),
            "bearings": ("id", "bearing", "sigma"),
            "ranges": ("id", "range", "sigma"),
        }
        for stream, rows in self.observations.items():
            if not rows:
                continue
            for r in rows:
                if r[0] not in self.pose_ids:
                    raise InputError(
                        f"observation from pose {r[0]}, which no edge or vertex has", name, r[-1]
                    )
            table = np.array([(self._time(r[0]),) + tuple(r[1:-1]) for r in rows], dtype=float)
            o = np.lexsort((table[:, 1], table[:, 0]))
            table = table[o]
            streams[stream] = Stream(stream, name, table[:, 0], cols[stream], table[:, 1:])
        gt = None
        if self.groundtruth:
            g = np.array(sorted((self._time(i), x, y, th) for i, x, y, th in self.groundtruth))
            gt = Stream("groundtruth", name, g[:, 0], ("x", "y", "theta"), g[:, 1:])
        first = order[0]
        initial = np.array(self.vertices[first], dtype=float) if first in self.vertices else None
        # without times in the file every stamp is a pose id: made up, not measured
        invented = () if self.times else tuple(streams)
        return SensorLog(
            name,
            streams,
            dict(self.landmark_map),
            gt,
            dict(self.repairs),
            initial,
            invented_times=invented,
        )


LineParser = Callable[[GraphBuilder, list[str], int], None]


def read_lines(
    path, parsers: dict[str, LineParser], refused: dict[str, str], builder: GraphBuilder
) -> GraphBuilder:
    """Feed every line of ``path`` to ``parsers[tag]``; a refused or unknown tag is an InputError.

    ``refused`` maps a tag to the reason it is not read. Blank lines and ``#`` comments are
    skipped; rows are 1-based line numbers.
    """
    name = builder.file
    with open(path, encoding="utf-8", errors="replace") as fh:
        for row, line in enumerate(fh, start=1):
            cells = line.split()
            if not cells or cells[0].startswith("#"):
                continue
            tag = cells[0]
            fn = parsers.get(tag)
            if fn is not None:
                fn(builder, cells, row)
                continue
            if tag in refused:
                raise InputError(f"line type '{tag}' is not supported: {refused[tag]}", name, row)
            if tag.startswith(THREE_D_PREFIXES):
                raise InputError(
                    f"3-D pose-graph line '{tag}' (only 2-D graphs are supported)", name, row
                )
            raise InputError(f"unknown line type '{tag}'", name, row)
    return builder
