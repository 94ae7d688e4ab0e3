"""Output file writers and readers: trajectory.csv, trajectory.tum, metrics.json.

TUM files: ``<estimator>.tum`` (``ekf.tum``, so evo's legend names the estimator), the same
content as ``trajectory.tum`` (kept as an alias), and ``groundtruth.tum`` whenever the log has
ground truth. ``trajectory.mcap`` (ROS 2) is :mod:`odofuse.outputs_ros`.

Every file is written atomically through :mod:`odofuse.io.atomic`, so a failure leaves no
half-written file. The picture is :mod:`odofuse.plotting`'s; the whole output folder of a run
(all four files, all or nothing) is :func:`odofuse.rundir.write_outputs`.
"""

from __future__ import annotations

import io
import json
import math
import os
from pathlib import Path

import numpy as np

from odofuse.errors import InputError
from odofuse.io.atomic import atomic_write, atomic_write_text
from odofuse.se2 import wrap
from odofuse.trajectory import Trajectory, pose_blocks

CSV_HEADER = (
    "t",
    "x",
    "y",
    "theta",
    "var_x",
    "cov_xy",
    "cov_xtheta",
    "var_y",
    "cov_ytheta",
    "var_theta",
)
#: (row, col) of the covariance entries in CSV_HEADER order after the pose.
_COV_IDX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


#: Rows formatted and written per block: bounds the text held in memory (about 200 bytes a
#: row) whatever the trajectory's length.
_ROWS = 1 << 14


def _csv_table(traj: Trajectory, rows: slice) -> np.ndarray:
    """``trajectory.csv`` values of ``rows``, shape (n, 10): t, pose (heading wrapped), cov."""
    t = traj.t[rows]
    table = np.empty((len(t), len(CSV_HEADER)))
    table[:, 0] = t
    table[:, 1:3] = traj.poses[rows, :2]
    table[:, 3] = wrap(traj.poses[rows, 2])
    if traj.covariances is None:
        table[:, 4:] = np.nan
    else:
        cov = traj.covariances[rows]
        for k, (i, j) in enumerate(_COV_IDX):
            table[:, 4 + k] = cov[:, i, j]
    return table


def _tum_table(traj: Trajectory, rows: slice) -> np.ndarray:
    """TUM values of ``rows``, shape (n, 8): t, x, y, z = 0, quaternion of the yaw."""
    t = traj.t[rows]
    table = np.zeros((len(t), 8))
    table[:, 0] = t
    table[:, 1:3] = traj.poses[rows, :2]
    table[:, 4:] = yaw_to_quaternion(traj.poses[rows, 2])
    return table


def _write_rows(fh, traj: Trajectory, make, sep: str) -> None:
    """Write the rows ``make(traj, rows)`` to the text file ``fh`` in blocks of ``_ROWS``,
    ``%.17g`` per value.

    A column that holds one value throughout a block (TUM's z, qx, qy; absent covariances) is
    formatted once into that block's row format.
    """
    for k in range(0, len(traj), _ROWS):
        table = make(traj, slice(k, k + _ROWS))
        bits = table.view(np.int64)  # the same bits: -0.0 and 0.0 print differently
        same = (bits == bits[:1]).all(axis=0)
        cells = [f"{float(v):.17g}" if c else "%.17g" for v, c in zip(table[0], same, strict=True)]
        fmt = sep.join(cells) + "\n"
        block = table[:, ~same].tolist()
        fh.write("".join([fmt % tuple(row) for row in block]))


def _text(traj: Trajectory, make, sep: str, header: str | None = None) -> str:
    out = io.StringIO()
    if header is not None:
        out.write(header + "\n")
    _write_rows(out, traj, make, sep)
    return out.getvalue()


def _atomic_table(path, traj: Trajectory, make, sep: str, header: str | None = None) -> Path:
    """Write a table atomically, block by block (never the whole text in memory)."""

    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            if header is not None:
                fh.write(header + "\n")
            _write_rows(fh, traj, make, sep)
            fh.flush()
            os.fsync(fh.fileno())

    return atomic_write(path, write)


def trajectory_csv_text(traj: Trajectory) -> str:
    """The ``trajectory.csv`` content: one row per pose, covariance in the world frame.

    Values use ``%.17g`` (round-trips every float64 exactly); a trajectory without
    covariances gets ``nan`` in the six covariance columns.
    """
    return _text(traj, _csv_table, ",", ",".join(CSV_HEADER))


def yaw_to_quaternion(theta) -> np.ndarray:
    """Unit quaternion ``(N, 4)`` as ``[qx, qy, qz, qw]`` of a rotation by ``theta`` about z."""
    half = 0.5 * np.asarray(theta, dtype=float)
    z = np.zeros_like(half)
    return np.stack([z, z, np.sin(half), np.cos(half)], axis=-1)


def trajectory_tum_text(traj: Trajectory) -> str:
    """The TUM content: ``t x y z qx qy qz qw`` per line, z = 0, yaw quaternion (evo-readable)."""
    return _text(traj, _tum_table, " ")


def write_trajectory_csv(path: str | Path, traj: Trajectory) -> Path:
    """Write ``trajectory.csv`` atomically (:func:`trajectory_csv_text`, in blocks)."""
    return _atomic_table(path, traj, _csv_table, ",", ",".join(CSV_HEADER))


#: Header of ``landmarks.csv``: SLAM landmark estimates, world frame, covariance in m^2.
LANDMARK_COLUMNS = ("id", "x", "y", "var_x", "cov_xy", "var_y")


def landmarks_csv_text(landmarks: dict, covariances: dict | None = None) -> str:
    """``landmarks.csv`` content: one row per landmark id (sorted), covariance ``nan`` when
    the estimator gave none.

    Parameters
    ----------
    landmarks : dict
        id -> ``[x, y]`` (m, world frame).
    covariances : dict, optional
        id -> ``[var_x, cov_xy, var_y]`` (m^2).
    """
    covariances = covariances or {}
    lines = [",".join(LANDMARK_COLUMNS)]
    for lid in sorted(landmarks, key=int):
        c = covariances.get(lid, [math.nan] * 3)
        vals = [*landmarks[lid], *c]
        lines.append(f"{int(lid)}," + ",".join(f"{float(v):.17g}" for v in vals))
    return "\n".join(lines) + "\n"


def write_landmarks_csv(path: str | Path, landmarks: dict, covariances: dict | None = None):
    """Write ``landmarks.csv`` atomically (:func:`landmarks_csv_text`)."""
    return atomic_write_text(path, landmarks_csv_text(landmarks, covariances))


def write_tum(path: str | Path, traj: Trajectory) -> Path:
    """Write a TUM trajectory file atomically (:func:`trajectory_tum_text`, in blocks)."""
    return _atomic_table(path, traj, _tum_table, " ")


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def json_ready(obj):
    """Replace non-finite floats with None so that metrics.json is strict JSON."""
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_metrics(path: str | Path, metrics: dict) -> Path:
    """Write ``metrics.json`` atomically (sorted keys, non-finite numbers as ``null``)."""
    text = json.dumps(json_ready(metrics), indent=2, sort_keys=True, default=_json_default)
    return atomic_write_text(path, text + "\n")


#: How ``metrics.json`` names a config file that ships inside the package.
PACKAGED_PREFIX = "odofuse:"


def run_path(path, run_dir) -> str:
    """``path`` as ``metrics.json`` and the batch summary record it: relative to ``run_dir``.

    One rule, so that a run folder can be read from any working directory and moved
    together with its log: a file or folder is written relative to ``run_dir`` (the run
    folder, or a batch's OUT); ``builtin:NAME`` and ``<...>`` (no file) stay as they are; a
    config that ships inside the package is ``odofuse:default_configs/NAME.yaml``.
    :func:`resolve_run_path` reads it back.
    """
    s = str(path)
    if s.startswith(("builtin:", "<", PACKAGED_PREFIX)) or not s:
        return s
    p = Path(s).expanduser().absolute()
    package = Path(__file__).resolve().parent
    try:
        return PACKAGED_PREFIX + p.resolve().relative_to(package).as_posix()
    except ValueError:
        pass
    return Path(os.path.relpath(p, Path(run_dir).expanduser().absolute())).as_posix()


def resolve_run_path(value: str, run_dir) -> str:
    """The path :func:`run_path` wrote, usable from the current working directory."""
    s = str(value)
    if s.startswith(("builtin:", "<")):
        return s
    if s.startswith(PACKAGED_PREFIX):
        return str(Path(__file__).resolve().parent / s.removeprefix(PACKAGED_PREFIX))
    p = Path(s).expanduser()
    return os.path.normpath(p if p.is_absolute() else Path(run_dir) / p)


def tum_name(estimator: str) -> str:
    """``<estimator>.tum`` with characters other than letters, digits, ``-`` and ``_`` as ``_``."""
    name = estimator.rsplit(":", 1)[-1] or "trajectory"
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name) + ".tum"


def evo_t_max_diff(t_est, t_gt) -> float:
    """The ``--t_max_diff`` (s) evo needs to match every estimate pose inside the ground truth.

    evo pairs each pose of the sparser trajectory with the nearest stamp of the other within
    ``t_max_diff``: this is the largest such distance over the estimate poses within the
    ground truth's time span (0 when they share stamps).
    """
    t_est, t_gt = np.asarray(t_est, dtype=float), np.asarray(t_gt, dtype=float)
    if np.any(t_gt[1:] < t_gt[:-1]):
        t_gt = np.sort(t_gt)
    largest = -math.inf  # the max over blocks of estimate times: the same value, bounded memory
    for b in pose_blocks(t_est.size):
        tb = t_est[b]
        tb = tb[(tb >= t_gt[0]) & (tb <= t_gt[-1])]
        if tb.size:
            i = np.clip(np.searchsorted(t_gt, tb), 1, t_gt.size - 1)
            gap = np.minimum(np.abs(tb - t_gt[i - 1]), np.abs(t_gt[i] - tb))
            largest = max(largest, float(gap.max()))
    return math.nan if largest == -math.inf else largest


def read_trajectory_csv(path: str | Path) -> Trajectory:
    """Read a ``trajectory.csv`` written by :func:`write_trajectory_csv`.

    A file with only ``t,x,y,theta`` (no covariance columns) or with ``nan`` covariances gives
    ``covariances=None``.
    """
    name = str(path)
    header, data, lines = read_table_allow_nan(path)
    for col in CSV_HEADER[:4]:
        if col not in header:
            raise InputError("missing column", name, 1, col)
    if data.shape[0] == 0:
        raise InputError("no poses", name, 2)
    idx = [header.index(c) for c in CSV_HEADER[:4]]
    pose_part = data[:, idx]
    if not np.isfinite(pose_part).all():
        i, j = np.argwhere(~np.isfinite(pose_part))[0]
        raise InputError("value is not finite", name, int(lines[i]), CSV_HEADER[j])
    covs = None
    if all(c in header for c in CSV_HEADER[4:]):
        flat = data[:, [header.index(c) for c in CSV_HEADER[4:]]]
        if np.isfinite(flat).all():
            covs = np.empty((len(data), 3, 3))
            for k, (i, j) in enumerate(_COV_IDX):
                covs[:, i, j] = covs[:, j, i] = flat[:, k]
    return Trajectory(pose_part[:, 0], pose_part[:, 1:4], covs)


def read_table_allow_nan(path: str | Path):
    """Like :func:`odofuse.io.csvlog.read_table` but accepting ``nan`` cells (covariances)."""
    name = str(path)
    with open(path, encoding="utf-8-sig") as fh:
        rows = [(k + 1, line) for k, line in enumerate(fh.read().splitlines()) if line.strip()]
    if not rows:
        raise InputError("empty file: expected a header line", name, 1)
    header = tuple(c.strip() for c in rows[0][1].split(","))
    data = np.empty((len(rows) - 1, len(header)))
    lines = np.array([k for k, _ in rows[1:]], dtype=np.int64)
    for r, (k, line) in enumerate(rows[1:]):
        cells = line.split(",")
        if len(cells) != len(header):
            raise InputError(f"{len(cells)} cells instead of {len(header)}", name, k)
        for j, cell in enumerate(cells):
            try:
                data[r, j] = float(cell)
            except ValueError:
                raise InputError(f"not a number: {cell.strip()!r}", name, k, header[j]) from None
    return header, data, lines


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM file (``t x y z qx qy qz qw``; ``#`` comments) into a planar trajectory.

    The heading is the yaw of the quaternion, ``atan2(2 (qw qz + qx qy), 1 - 2 (qy^2 + qz^2))``.
    """
    name = str(path)
    ts, rows = [], []
    with open(path, encoding="utf-8") as fh:
        for k, line in enumerate(fh, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            cells = s.replace(",", " ").split()
            if len(cells) != 8:
                raise InputError(f"{len(cells)} values instead of 8 (t x y z qx qy qz qw)", name, k)
            try:
                vals = [float(c) for c in cells]
            except ValueError:
                raise InputError("not a number", name, k) from None
            if not all(math.isfinite(v) for v in vals):
                raise InputError("value is not finite", name, k)
            ts.append(vals[0])
            rows.append(vals[1:])
    if not rows:
        raise InputError("no poses in TUM file", name)
    a = np.asarray(rows)
    qx, qy, qz, qw = a[:, 3], a[:, 4], a[:, 5], a[:, 6]
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy**2 + qz**2))
    return Trajectory(np.asarray(ts), np.column_stack([a[:, 0], a[:, 1], yaw]))


def read_trajectory(path: str | Path) -> Trajectory:
    """Read ``.csv`` (trajectory.csv or groundtruth.csv) or TUM (any other extension)."""
    path = Path(path)
    if path.is_dir():
        path = path / "trajectory.csv"
    if path.suffix.lower() == ".csv":
        return read_trajectory_csv(path)
    return read_tum(path)
