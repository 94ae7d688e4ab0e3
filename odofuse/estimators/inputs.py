"""Checks of the readings a live :class:`~odofuse.estimators.localizer.Localizer` is fed.

The streaming API gets the same guards as a CSV log (:mod:`odofuse.io.csvlog`): an unknown
stream, a reading that is not a mapping of numbers, a missing, non-numeric, non-finite or
out-of-range (``|value| > MAX_MAGNITUDE``) time or value, an input of the wrong length each
raise an :class:`~odofuse.errors.InputError` naming the stream, the time and the field. Exact
duplicates are dropped and counted as the CSV loader's default repair (``drop_exact``) does,
and a second reading at the same time (and ``id``) with different values is an error, as it
is offline.

This module owns the check functions and :class:`Duplicates`, the bounded memory of recent
readings that finds the duplicates.
"""

from __future__ import annotations

import math
import numbers
from collections import deque
from collections.abc import Mapping

import numpy as np

from odofuse.errors import InputError
from odofuse.io.csvlog import MAX_MAGNITUDE, excerpt
from odofuse.status.findings import MOSTLY_REJECTED, Finding

#: What ``Localizer.add_measurement`` / ``add_odometry`` return.
USED, REJECTED, BUFFERED, DROPPED, DUPLICATE = (
    "used",
    "rejected",
    "buffered",
    "dropped",
    "duplicate",
)


def _number(value, what: str, field: str, t=None) -> float:
    """``value`` as a finite float within :data:`MAX_MAGNITUDE`, else an InputError."""
    if type(value) is float and -MAX_MAGNITUDE <= value <= MAX_MAGNITUDE:
        return value  # the common case, fast (NaN fails the comparison)
    at = f" at t={t:.6f}" if t is not None else ""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(
            f"{what}{at}: '{field}' must be a number, got {excerpt(repr(value))}", column=field
        )
    x = float(value)
    if not math.isfinite(x):
        raise InputError(f"{what}{at}: '{field}' is non-finite ({x})", column=field)
    if abs(x) > MAX_MAGNITUDE:
        raise InputError(
            f"{what}{at}: '{field}' = {x:g} is out of range (|value| > {MAX_MAGNITUDE:g})",
            column=field,
        )
    return x


def check_row(stream, row, known) -> tuple[float, dict]:
    """Validate a measurement reading; returns its time and a plain dict of floats.

    Parameters
    ----------
    stream : str
        The stream name; must be one of ``known``.
    row : Mapping
        ``t`` (s) and the stream's columns (numbers).
    known : collection of str
        The streams this Localizer has a model (or gyrodometry) for.
    """
    if not isinstance(stream, str) or stream not in known:
        names = ", ".join(sorted(known)) or "none"
        raise InputError(
            f"unknown stream {excerpt(repr(stream))}; this Localizer has models for: {names}"
        )
    what = f"stream '{stream}'"
    if not isinstance(row, Mapping):
        raise InputError(
            f"{what}: a reading must be a mapping of column -> number, got {type(row).__name__}"
        )
    if "t" not in row:
        raise InputError(f"{what}: the reading has no time 't'", column="t")
    t = _number(row["t"], what, "t")
    out = {"t": t}
    for key, value in row.items():
        if key != "t":
            out[str(key)] = _number(value, what, str(key), t)
    return t, out


def check_measurement(stream: str, model, t: float, row: dict, x: np.ndarray) -> np.ndarray:
    """The row has what the model reads (``z``; a landmark ``id`` in the map, through ``h`` at
    any state ``x`` of the right length), and it is finite; checked before the filter is
    touched, so a bad late reading cannot leave a half-done replay. Returns ``z``."""
    try:
        z = np.asarray(model.z(row), dtype=float)
        if "id" in row:  # a landmark/beacon id must be in the map (h looks it up)
            model.h(x, row)
    except KeyError as exc:
        raise InputError(
            f"stream '{stream}' at t={t:.6f}: no column {exc}", column=str(exc).strip("'")
        ) from None
    except InputError:
        raise
    except ValueError as exc:
        raise InputError(f"stream '{stream}' at t={t:.6f}: {excerpt(str(exc), 200)}") from None
    if not np.all(np.isfinite(z)):
        raise InputError(f"stream '{stream}' at t={t:.6f}: non-finite value {z.tolist()}")
    return z


def check_odometry(t, u, names) -> tuple[float, np.ndarray]:
    """Validate one odometry step: time ``t`` (s) and drive input ``u`` of ``len(names)``.

    Returns the time and a copy of the input as a float array (the caller may reuse its
    buffer).
    """
    t = _number(t, "odometry", "t")
    if type(u) is np.ndarray and u.dtype == np.float64 and u.shape == (len(names),):
        arr = u.copy()  # the common case, fast
    else:
        arr = _input_array(t, u, names)
    for j, x in enumerate(arr.tolist()):
        if not -MAX_MAGNITUDE <= x <= MAX_MAGNITUDE:  # NaN fails too
            _number(x, "odometry", names[j], t)
    return t, arr


def _input_array(t: float, u, names) -> np.ndarray:
    what = f"odometry at t={t:.6f}"
    if u is None or isinstance(u, str | bytes | Mapping):
        raise InputError(f"{what}: input must be a sequence of numbers, got {type(u).__name__}")
    try:
        arr = np.array(u, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: input is not a sequence of numbers", column="u") from None
    if arr.shape != (len(names),):
        raise InputError(
            f"{what}: input must have shape ({len(names)},) for ({', '.join(names)}), "
            f"got {arr.shape}",
            column="u",
        )
    return arr


class Duplicates:
    """Recent readings per stream, to drop exact repeats of a ``(t, id)`` and refuse conflicts.

    Holds the readings of the last ``window`` seconds (the late window plus the newest time
    stamp), so memory stays bounded however long the stream runs.
    """

    def __init__(self, window: float) -> None:
        self.window = float(window)
        self.seen: dict[tuple, dict] = {}
        self.order: deque[tuple] = deque()
        self.count: dict[str, int] = {}
        self.last_odometry: tuple[float, np.ndarray] | None = None

    def odometry(self, t: float, u: np.ndarray) -> bool:
        """True (and counted) for an exact repeat of the previous step; an error for a clash."""
        last = self.last_odometry
        if last is not None and t == last[0]:
            if np.array_equal(u, last[1]):
                self.count["odometry"] = self.count.get("odometry", 0) + 1
                return True
            raise InputError(
                f"odometry at t={t:.6f}: a second step at this time with a different input "
                "(as in a CSV log, only exact duplicates are dropped)",
                column="u",
            )
        self.last_odometry = (t, u)  # check_odometry's own copy, never changed
        return False

    def check(self, stream: str, t: float, row: dict, now: float) -> bool:
        """True (and counted) for an exact repeat; an error for a conflicting repeat."""
        horizon = min(now, t) - self.window
        while self.order and self.order[0][1] < horizon:
            self.seen.pop(self.order.popleft(), None)
        key = (stream, t, row.get("id"))
        first = self.seen.get(key)
        if first is None:
            self.seen[key] = row
            self.order.append(key)
            return False
        if first == row:
            self.count[stream] = self.count.get(stream, 0) + 1
            return True
        differs = next(k for k in sorted(set(first) | set(row)) if first.get(k) != row.get(k))
        raise InputError(
            f"stream '{stream}' at t={t:.6f}: a second reading at this time"
            f"{' and id' if 'id' in row else ''} with different values (as in a CSV log, "
            "only exact duplicates are dropped)",
            column=differs,
        )


def dropped_findings(used: dict, rejected: dict, dropped: dict, span=(None, None)) -> list:
    """A degrading finding per stream of which more than half was dropped unused.

    A reading is dropped when it arrives older than the late window or after the last
    odometry step; most of a stream dropped means its clock (units, offset) or its latency
    does not match the odometry's, and the estimate went without it.
    """
    out = []
    for s in sorted(dropped):
        d = int(dropped.get(s, 0))
        n = d + int(used.get(s, 0)) + int(rejected.get(s, 0))
        if d and d / n > MOSTLY_REJECTED:
            out.append(
                Finding(
                    "dropped",
                    f"{d} of {n} readings ({100 * d / n:.0f} %) dropped unused (older than the "
                    "late window or after the last odometry): is this stream's clock in "
                    "seconds, on the odometry's time base?",
                    sensor=s,
                    t_start=span[0],
                    t_end=span[1],
                    figure=d / n,
                )
            )
    return out
