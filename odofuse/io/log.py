"""The in-memory form of a log: named, validated time series in SI units."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Stream:
    """One sensor stream: time stamps and named value columns.

    Parameters
    ----------
    name : str
        Stream name (``"wheels"``, ``"odometry"``, ``"ranges"``, ...).
    source : str
        Where it came from (file path), for error messages.
    t : ndarray, shape (N,)
        Time stamps in seconds, non-decreasing.
    columns : tuple of str
        Value column names (without ``t``).
    values : ndarray, shape (N, C)
        Values in SI units.
    """

    name: str
    source: str
    t: np.ndarray
    columns: tuple[str, ...]
    values: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).reshape(-1)
        values = np.asarray(self.values, dtype=float).reshape(t.size, len(self.columns))
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "columns", tuple(self.columns))

    def __len__(self) -> int:
        return self.t.size

    def __getitem__(self, column: str) -> np.ndarray:
        try:
            return self.values[:, self.columns.index(column)]
        except ValueError:
            msg = f"{self.source}: stream '{self.name}' has no column '{column}'"
            raise KeyError(msg) from None

    def between(self, t_start: float, t_end: float) -> Stream:
        """The rows with ``t_start <= t <= t_end`` (s), as a new stream."""
        keep = (self.t >= t_start) & (self.t <= t_end)
        return Stream(self.name, self.source, self.t[keep], self.columns, self.values[keep])

    def row(self, i: int) -> dict[str, float]:
        """Row ``i`` as ``{"t": ..., column: value, ...}``."""
        out = {"t": float(self.t[i])}
        out.update(zip(self.columns, map(float, self.values[i]), strict=True))
        return out


@dataclass(frozen=True)
class SensorLog:
    """A whole log: streams by name, the landmark map, optional ground truth and repairs.

    ``groundtruth`` has columns ``("x", "y", "theta")`` and is never fed to an estimator.
    ``repairs`` counts documented repairs (``"wheels.duplicate_t"``, ``"wheels.rollover"``...).
    ``initial_pose`` is the dataset's own published start pose when it has one (m, m, rad).
    ``ros`` holds what a ROS bag says about frames and noise (empty for other logs): see
    :func:`odofuse.io.bags.read_bag`. ``invented_times`` names the streams whose times the
    loader made up rather than read (a pose graph without times stamps pose ``k`` at
    ``t = k`` s): no plausibility check judges a speed or a time unit by them
    (:mod:`odofuse.io.plausibility`).
    """

    source: str
    streams: dict[str, Stream]
    landmarks: dict[int, np.ndarray] = field(default_factory=dict)
    groundtruth: Stream | None = None
    repairs: dict[str, int] = field(default_factory=dict)
    initial_pose: np.ndarray | None = None
    ros: dict = field(default_factory=dict)
    #: Plausibility findings about the data (odofuse.io.plausibility): ``warnings`` lines.
    findings: tuple = ()
    invented_times: tuple[str, ...] = ()

    def has(self, name: str) -> bool:
        return name in self.streams and len(self.streams[name]) > 0

    def window(self, t_start: float, t_end: float) -> SensorLog:
        """The rows of every stream (and of ground truth) with ``t_start <= t <= t_end`` (s).

        The map and the repair counts are the whole log's; ``initial_pose`` is kept only when
        the window starts at or before the log's first row (it is the pose of the log's start).
        Cumulative streams (``wheels.csv``) stay cumulative: the window's first row is the
        start of its first step.
        """
        first = min((float(s.t[0]) for s in self.streams.values() if len(s)), default=t_start)
        return SensorLog(
            self.source,
            {name: s.between(t_start, t_end) for name, s in self.streams.items()},
            dict(self.landmarks),
            None if self.groundtruth is None else self.groundtruth.between(t_start, t_end),
            dict(self.repairs),
            self.initial_pose if t_start <= first else None,
            invented_times=self.invented_times,
        )


def time_ordered(
    stream: Stream, key_columns: tuple[str, ...] | None = ()
) -> tuple[Stream, int, int]:
    """``stream`` sorted by time (stable), without rows repeating an earlier (t, key) pair.

    ``key_columns`` names the columns that, with ``t``, identify a measurement: ``("id",)`` for
    ranges to several beacons, ``()`` for one value per time stamp; with ``None`` only rows
    equal in every column are repeats.

    Returns
    -------
    stream : Stream
    moved : int
        Rows whose position changed by the sort.
    dropped : int
        Repeated rows removed (the first occurrence is kept).
    """
    order = np.argsort(stream.t, kind="stable")
    moved = int(np.count_nonzero(order != np.arange(order.size)))
    table = np.column_stack([stream.t, stream.values])[order]
    if key_columns is None:
        key = list(range(table.shape[1]))
    else:
        key = [0] + [1 + stream.columns.index(c) for c in key_columns]
    _, first = np.unique(table[:, key], axis=0, return_index=True)
    keep = np.zeros(len(table), dtype=bool)
    keep[first] = True
    table = table[keep]
    out = Stream(stream.name, stream.source, table[:, 0], stream.columns, table[:, 1:])
    return out, moved, int(np.count_nonzero(~keep))
