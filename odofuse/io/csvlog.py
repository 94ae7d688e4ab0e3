"""Reading a log folder of CSV files (shared spec section 1) into a validated ``SensorLog``.

Every stream file has a header line and ``t`` (seconds) as its first column; ``map.csv`` holds
``id, x, y``. The numbers are parsed by :func:`odofuse.io.csvtable.read_table` (numpy's C
reader for a plain file; the exact line-by-line path, which names the offending line, for
anything else); this module owns the checks of each stream's columns and values and the
repairs.

Bad input (spec section 5) either raises :class:`odofuse.errors.InputError` naming the file, the
1-based line number (the header is line 1) and the column, or is repaired and counted in
``SensorLog.repairs``:

``<stream>.duplicate_rows``
    exact duplicate rows (same time stamp and same values) dropped.
``<stream>.reordered``, ``<stream>.conflicting_dropped``
    only under an opt-in repair policy (:data:`REPAIR`): rows moved by sorting, rows dropped
    because they repeat a time stamp (and id) with different values.
``wheels.rollover_unwraps``
    encoder counter wrap-arounds unwrapped (only with an ``encoder`` block).
``<stream>.gaps``
    time gaps longer than ``gap_factor`` times the median sample interval: counted, not
    repaired (the estimators simply integrate across them).

See ``docs/formats.md`` for the full table.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse.errors import InputError
from odofuse.io.csvtable import (  # noqa: F401  (re-exported: the bounds are spec section 5)
    EXCERPT_CHARS,
    MAX_LINE_BYTES,
    MAX_MAGNITUDE,
    excerpt,
    read_table,
)
from odofuse.io.log import SensorLog, Stream, time_ordered
from odofuse.se2 import wrap

#: Required value columns (after ``t``) of the streams named by the spec; ``None``: any.
STREAM_COLUMNS: dict[str, tuple[str, ...] | None] = {
    "wheels": None,
    "odometry": ("ds", "dtheta"),
    "gyro": ("wz",),
    "compass": ("heading",),
    "gps": None,  # (x, y) or (lat, lon), optional sigma; checked in _check_gps
    "ranges": ("id", "range"),
    "landmarks": ("id", "range", "bearing"),
    "groundtruth": ("x", "y", "theta"),
}
#: Optional extra value columns accepted for a stream.
OPTIONAL_COLUMNS: dict[str, tuple[str, ...]] = {
    # the relative pose and covariance that pose-graph logs carry (odofuse.io.posegraph)
    "odometry": ("dx", "dy", "cov_xx", "cov_xy", "cov_xt", "cov_yy", "cov_yt", "cov_tt"),
    "gps": ("sigma",),
    "ranges": ("sigma",),
    "landmarks": ("sigma_range", "sigma_bearing"),
}
#: Streams where several rows may share a time stamp when they differ in ``id``.
KEYED_STREAMS = ("ranges", "landmarks")
#: Default repair policy of a CSV log (config ``log: {path, repair: {sort, duplicates}}``):
#: ``sort`` (bool): rows whose ``t`` goes backwards are sorted (stable) and counted as
#: ``<stream>.reordered`` instead of being an error. ``duplicates``: rows repeating the time
#: stamp (and ``id`` in ranges/landmarks) of an earlier row are
#: ``"error"``: an error, even when every value is equal;
#: ``"drop_exact"`` (default): dropped when every value is equal (``<stream>.duplicate_rows``),
#: an error when a value differs;
#: ``"keep_first"``: dropped, the first row kept (``duplicate_rows`` / ``conflicting_dropped``);
#: ``"drop_conflicting"``: exact copies dropped; when the rows disagree, all of them are dropped
#: (``<stream>.conflicting_dropped``), since the log does not say which one is right.
REPAIR: dict = {"sort": False, "duplicates": "drop_exact"}
REPAIR_DUPLICATES = ("error", "drop_exact", "keep_first", "drop_conflicting")
#: A time gap counts when it exceeds this many median sample intervals.
GAP_FACTOR = 10.0

_TWO_PI = 2.0 * math.pi


def _check_columns(stream: str, header: tuple[str, ...], name: str) -> None:
    values = header[1:]
    if stream == "gps":
        if {"x", "y"} <= set(values):
            required = ("x", "y")
        elif {"lat", "lon"} <= set(values):
            required = ("lat", "lon")
        else:
            missing = "y" if "x" in values else "lon" if "lat" in values else "x"
            raise InputError("gps.csv needs columns 't, x, y' or 't, lat, lon'", name, 1, missing)
    else:
        required = STREAM_COLUMNS.get(stream)
        if required is None:
            if not values:
                raise InputError("no value columns after 't'", name, 1)
            return
    for col in required:
        if col not in values:
            raise InputError(
                f"missing column (expected {', '.join(('t',) + required)})", name, 1, col
            )
    optional = OPTIONAL_COLUMNS.get(stream, ())
    allowed = set(required) | set(optional)
    hint = f"; optional {', '.join(optional)}" if optional else ""
    for col in values:
        if col not in allowed:
            raise InputError(
                f"unexpected column (expected {', '.join(('t',) + required)}{hint})",
                name,
                1,
                col,
            )


def _dedupe_and_order(
    stream: str, header, data, lines, name: str, repairs: dict, repair: dict | None = None
):
    """Check time order and repeated rows under the log's repair policy (:data:`REPAIR`)."""
    policy = {**REPAIR, **(repair or {})}
    t = data[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size and not policy["sort"]:
        i = int(back[0]) + 1
        raise InputError(
            f"time goes backwards: {float(t[i])!r} after {float(t[i - 1])!r}",
            name,
            int(lines[i]),
            "t",
        )
    if back.size:
        order = np.argsort(t, kind="stable")
        _add(repairs, f"{stream}.reordered", int(np.count_nonzero(order != np.arange(t.size))))
        data, lines, t = data[order], lines[order], t[order]
    dt = np.diff(t)
    if not np.any(dt == 0):
        return data, lines
    if stream in KEYED_STREAMS:
        key_cols = [0, header.index("id")]
    elif stream in STREAM_COLUMNS:
        key_cols = [0]
    else:
        key_cols = list(range(len(header)))  # unknown streams: only exact duplicates matter
    keyname = "time stamp" if len(key_cols) == 1 else "time stamp and id"
    mode = policy["duplicates"]
    drop = np.zeros(len(t), dtype=bool)
    bounds = np.flatnonzero(np.concatenate([[True], dt != 0, [True]]))
    for start, end in zip(bounds[:-1], bounds[1:], strict=True):
        if end - start < 2:
            continue
        groups: dict[tuple, list[int]] = {}
        for i in range(start, end):
            groups.setdefault(tuple(data[i, key_cols]), []).append(i)
        for g in groups.values():
            if len(g) < 2:
                continue
            first, rest = g[0], g[1:]
            differ = [k for k in rest if not np.array_equal(data[k], data[first])]
            if mode == "error" or (differ and mode == "drop_exact"):
                k = differ[0] if differ else rest[0]
                what = "a different value than" if differ else "the same values as"
                j = int(np.flatnonzero(data[k] != data[first])[0]) if differ else key_cols[0]
                raise InputError(
                    f"duplicate {keyname} with {what} line {int(lines[first])}",
                    name,
                    int(lines[k]),
                    header[j],
                )
            if differ and mode == "drop_conflicting":
                drop[g] = True
                _add(repairs, f"{stream}.conflicting_dropped", len(g))
                continue
            drop[rest] = True
            _add(repairs, f"{stream}.duplicate_rows", len(rest) - len(differ))
            _add(repairs, f"{stream}.conflicting_dropped", len(differ))
    return data[~drop], lines[~drop]


def _add(repairs: dict, key: str, n: int) -> None:
    if n:
        repairs[key] = repairs.get(key, 0) + n


def _count_gaps(stream: str, t: np.ndarray, repairs: dict, gap_factor: float) -> None:
    dt = np.diff(t)
    dt = dt[dt > 0]
    if dt.size < 2:
        return
    gaps = int(np.count_nonzero(dt > gap_factor * np.median(dt)))
    if gaps:
        repairs[f"{stream}.gaps"] = gaps


def _range_error(name, header, data, lines, col, ok, what):
    j = header.index(col)
    i = int(np.flatnonzero(~ok)[0])
    raise InputError(f"{what}, got {float(data[i, j])!r}", name, int(lines[i]), col)


def _check_values(stream, header, data, lines, name, landmark_ids):
    """Out-of-range checks; returns data with angles wrapped to [-pi, pi)."""
    cols = {c: data[:, header.index(c)] for c in header}

    def need(col, ok, what):
        if col in cols and not np.all(ok(cols[col])):
            _range_error(name, header, data, lines, col, ok(cols[col]), what)

    data = data.copy()
    need("range", lambda v: v >= 0, "a range cannot be negative")
    need("sigma", lambda v: v > 0, "sigma must be positive")
    need("sigma_range", lambda v: v > 0, "sigma must be positive")
    need("sigma_bearing", lambda v: v > 0, "sigma must be positive")
    need("id", lambda v: v == np.round(v), "an id must be an integer")
    if stream == "gps":
        need("lat", lambda v: np.abs(v) <= 90, "latitude must be within [-90, 90] degrees")
        need("lon", lambda v: np.abs(v) <= 180, "longitude must be within [-180, 180] degrees")
    angle_cols = {
        "compass": ("heading",),
        "landmarks": ("bearing",),
        "groundtruth": ("theta",),
        "odometry": ("dtheta",),
    }.get(stream, ())
    for col in angle_cols:
        need(col, lambda v: np.abs(v) <= _TWO_PI, "an angle must be within [-2pi, 2pi] rad")
        if stream != "odometry":  # absolute angles are wrapped; increments keep their sign
            data[:, header.index(col)] = wrap(cols[col])
    if landmark_ids is not None and "id" in cols:
        known = np.isin(cols["id"], np.fromiter(landmark_ids, dtype=float, count=len(landmark_ids)))
        if not known.all():
            _range_error(name, header, data, lines, "id", known, "id is not in map.csv")
    return data


def _check_wrap_rate(counts, rollover, lines, name: str, cols) -> None:
    """Unwrapping takes a step of more than ``rollover / 2`` as a wrap. A counter moving less
    than that per row needs at least two rows to run through its range, so it wraps at most
    every other row: a column that "wraps" more often is aliased (e.g. ``rollover: 1``, which
    turned every step into zero motion), an error naming the column."""
    if rollover is None or counts.shape[0] < 3:
        return
    wraps = np.abs(np.diff(counts, axis=0)) > 0.5 * float(rollover)
    steps = counts.shape[0] - 1
    per = wraps.sum(axis=0)
    j = int(np.argmax(per))
    if per[j] > steps // 2 + 1:
        raise InputError(
            f"the counter wraps at {int(per[j])} of {steps} steps, more often than a counter "
            f"of {float(rollover):g} states can (every other row at most): check "
            "robot.encoder.rollover (the counter width)",
            name,
            int(lines[int(np.argmax(wraps[:, j])) + 1]),
            cols[j],
        )


def _wheel_ticks_to_rad(header, data, lines, name, encoder: dict, repairs: dict):
    """Convert encoder ticks to wheel angles (rad), unwrapping counter rollover.

    ``encoder``: ``ticks_per_rev`` (ticks per wheel revolution at the encoder), optional
    ``gear_ratio`` (wheel revolutions = encoder revolutions / gear_ratio, default 1),
    ``rollover`` (counter modulus, e.g. 65536; a step of more than half of it is a wrap) and
    ``columns`` (which wheels.csv columns are encoders; default every column whose name does
    not start with ``steer``).
    """
    from odofuse.encoders import Encoder

    enc = Encoder(
        float(encoder["ticks_per_rev"]),
        float(encoder.get("gear_ratio", 1.0)),
        encoder.get("rollover"),
    )
    cols = encoder.get("columns") or [c for c in header[1:] if not c.startswith("steer")]
    for col in cols:
        if col not in header:
            raise InputError("encoder column named in the config is missing", name, 1, col)
    idx = [header.index(c) for c in cols]
    _check_wrap_rate(data[:, idx], encoder.get("rollover"), lines, name, cols)
    data = data.copy()
    data[:, idx], unwraps = enc.convert(data[:, idx])
    if unwraps:
        repairs["wheels.rollover_unwraps"] = repairs.get("wheels.rollover_unwraps", 0) + unwraps
    return data


def read_stream(
    path: str | Path,
    stream: str | None = None,
    *,
    repairs: dict | None = None,
    encoder: dict | None = None,
    landmark_ids=None,
    gap_factor: float = GAP_FACTOR,
    repair: dict | None = None,
) -> Stream:
    """Read and validate one stream file.

    Parameters
    ----------
    path : str or Path
        The CSV file; its stem names the stream unless ``stream`` is given.
    stream : str, optional
        Stream name (``"wheels"``, ``"odometry"``, ...).
    repairs : dict, optional
        Counted repairs are added here (see module docstring).
    encoder : dict, optional
        Encoder block of the robot config; only used for ``wheels``.
    landmark_ids : collection of int, optional
        Known ids from ``map.csv``; ``id`` cells of ranges/landmarks must be among them.
    gap_factor : float
        Gap threshold in median sample intervals.
    repair : dict, optional
        Repair policy ``{sort, duplicates}`` (:data:`REPAIR`; default: no sorting, exact
        duplicates dropped).

    Returns
    -------
    Stream
        SI units; absolute angles wrapped to [-pi, pi).
    """
    path = Path(path)
    name = str(path)
    stream = stream or path.stem
    repairs = {} if repairs is None else repairs
    header, data, lines = read_table(path, "t")
    _check_columns(stream, header, name)
    if data.shape[0] == 0:
        raise InputError("no data rows after the header (empty stream)", name, 2)
    data, lines = _dedupe_and_order(stream, header, data, lines, name, repairs, repair)
    data = _check_values(stream, header, data, lines, name, landmark_ids)
    if stream == "wheels" and encoder:
        data = _wheel_ticks_to_rad(header, data, lines, name, encoder, repairs)
    _count_gaps(stream, data[:, 0], repairs, gap_factor)
    return Stream(stream, name, data[:, 0], header[1:], data[:, 1:])


def read_map(path: str | Path) -> dict[int, np.ndarray]:
    """Read ``map.csv`` (``id, x, y``) into ``{id: array([x, y])}`` (m, world frame)."""
    name = str(path)
    header, data, lines = read_table(path, first_column=None)
    for col in ("id", "x", "y"):
        if col not in header:
            raise InputError("missing column (expected id, x, y)", name, 1, col)
    for col in header:
        if col not in ("id", "x", "y"):
            raise InputError("unexpected column (expected id, x, y)", name, 1, col)
    ids = data[:, header.index("id")]
    ix, iy = header.index("x"), header.index("y")
    out: dict[int, np.ndarray] = {}
    for k, (i, line) in enumerate(zip(ids, lines, strict=False)):
        if i != round(i):
            raise InputError(f"an id must be an integer, got {i!r}", name, int(line), "id")
        if int(i) in out:
            raise InputError(f"id {int(i)} appears twice", name, int(line), "id")
        out[int(i)] = np.array([data[k, ix], data[k, iy]])
    return out


def read_csv_log(
    folder: str | Path,
    *,
    encoder: dict | None = None,
    gap_factor: float = GAP_FACTOR,
    repair: dict | None = None,
    groundtruth: bool = True,
) -> SensorLog:
    """Read a log folder (shared spec section 1).

    Every ``*.csv`` file whose header starts with ``t`` becomes a stream named after the file
    (the names of spec section 1 are validated strictly; other names are accepted as generic
    streams); ``map.csv`` becomes ``landmarks`` and ``groundtruth.csv`` the ground truth.

    Parameters
    ----------
    folder : str or Path
        The log folder.
    encoder : dict, optional
        The robot's encoder block (``ticks_per_rev``, ``gear_ratio``, ``rollover``); when
        given, ``wheels.csv`` is in ticks and is converted to radians here.
    gap_factor : float
        Time gaps above this many median sample intervals are counted as ``<stream>.gaps``.
    repair : dict, optional
        Repair policy ``{sort, duplicates}`` for every stream file (:data:`REPAIR`).
    groundtruth : bool
        False: ``groundtruth.csv`` is not opened at all (``odofuse tune`` must never see it).

    Returns
    -------
    SensorLog
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("log folder does not exist", str(folder))
    repairs: dict[str, int] = {}
    landmarks = read_map(folder / "map.csv") if (folder / "map.csv").exists() else {}
    ids = set(landmarks) if landmarks else None
    streams: dict[str, Stream] = {}
    skip = {"map.csv"} if groundtruth else {"map.csv", "groundtruth.csv"}
    groundtruth = None
    for path in sorted(folder.glob("*.csv")):
        if path.name in skip:
            continue
        stream = path.stem
        s = read_stream(
            path,
            stream,
            repairs=repairs,
            encoder=encoder if stream == "wheels" else None,
            landmark_ids=ids if stream in KEYED_STREAMS else None,
            gap_factor=gap_factor,
            repair=repair,
        )
        if stream == "groundtruth":
            groundtruth = s
        else:
            streams[stream] = s
    if not streams:
        raise InputError("no stream files (*.csv with a 't' column) in the log folder", str(folder))
    return SensorLog(str(folder), streams, landmarks, groundtruth, repairs)


def write_csv_log(log: SensorLog, folder: str | Path) -> tuple[list[Path], dict[str, int]]:
    """Write ``log`` as a log folder readable by :func:`read_csv_log` (values in SI units).

    Rows are sorted by time (stable) so that the folder satisfies the spec even when the source
    was not ordered (the Plaza1 ``TD`` ranges jump back in time twice), and a row whose time
    stamp (and ``id``) repeats an earlier row's is dropped (Plaza1 has two such range pairs).
    Files are written atomically (temporary file + rename).

    Returns
    -------
    paths : list of Path
        The written files.
    changes : dict
        ``{"<stream>.reordered": rows moved, "<stream>.duplicates_dropped": rows dropped}``,
        only for streams that needed it.
    """
    from odofuse.io.atomic import atomic_write_text

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    changes: dict[str, int] = {}
    items = list(log.streams.items())
    if log.groundtruth is not None:
        items.append(("groundtruth", log.groundtruth))
    for name, stream in items:
        if name not in STREAM_COLUMNS:
            key = None
        elif name in KEYED_STREAMS and "id" in stream.columns:
            key = ("id",)
        else:
            key = ()
        s, moved, dropped = time_ordered(stream, key)
        if moved:
            changes[f"{name}.reordered"] = moved
        if dropped:
            changes[f"{name}.duplicates_dropped"] = dropped
        table = np.column_stack([s.t, s.values])
        header = ",".join(("t",) + s.columns)
        body = "\n".join(",".join(map(_fmt, row)) for row in table.tolist())  # Python floats
        path = folder / f"{name}.csv"
        atomic_write_text(path, header + "\n" + body + "\n")
        written.append(path)
    if log.landmarks:
        rows = "\n".join(f"{i},{_fmt(p[0])},{_fmt(p[1])}" for i, p in sorted(log.landmarks.items()))
        atomic_write_text(folder / "map.csv", "id,x,y\n" + rows + "\n")
        written.append(folder / "map.csv")
    return written, changes


def _fmt(v: float) -> str:
    if float(v).is_integer() and abs(v) < 1e15:
        return str(int(v))
    return repr(float(v))
