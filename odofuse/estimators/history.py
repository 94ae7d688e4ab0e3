"""What the streaming :class:`~odofuse.estimators.localizer.Localizer` remembers.

This module owns the two growing stores of the Localizer and keeps both bounded:

* :class:`Track`, the filtered pose, its covariance and its time after every odometry step, in
  growable numpy blocks (104 bytes a step instead of three Python objects). A late replay cuts
  it back (:meth:`Track.truncate`). With ``keep_all=False`` (a live Localizer) it forgets
  the poses older than the late window, so its memory stays flat however long the stream
  runs; with ``keep_all=True`` (an offline run) it keeps every pose for the result.
* :class:`Step` and :class:`Steps`, the odometry steps inside the late window with the filter
  state before each, from which a late reading is replayed: at most one window of steps, so a
  replay costs O(window) and memory does not grow with the run;
* the gyro rate samples of gyrodometry and robust odometry (:func:`keep_rate_sample`,
  :func:`held_rate_integral`), also only as far back as a replay can reach.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from typing import NamedTuple

import numpy as np

#: Smallest block of a :class:`Track` (steps).
_MIN_BLOCK = 256


class Track:
    """Times (N,), poses (N, 3) and pose covariances (N, 3, 3) after each step.

    Indices are absolute (the initial pose is 0), also after old poses were forgotten.

    Parameters
    ----------
    t, x, P : float, ndarray (3,), ndarray (3, 3)
        The initial time (s), pose ``[x, y, theta]`` (map frame) and its covariance.
    keep_all : bool
        Keep every pose (offline); else only what :meth:`forget_before` leaves (live).
    """

    def __init__(self, t: float, x, P, keep_all: bool = True) -> None:
        self.keep_all = bool(keep_all)
        self._t = np.empty(_MIN_BLOCK)
        self._x = np.empty((_MIN_BLOCK, 3))
        self._P = np.empty((_MIN_BLOCK, 3, 3))
        self._n = 0  # stored rows
        self._offset = 0  # absolute index of stored row 0
        self._dead = 0  # absolute index before which rows may be dropped (live mode)
        self._finished = False  # a whole-run offline track (from_arrays): never appended to
        self.append(t, x, P)

    @classmethod
    def from_arrays(cls, t, x, P) -> Track:
        """A finished offline track holding times (N,), poses (N, 3) and covariances (N, 3, 3)
        as given (the compiled core's whole-run output, not copied: on a 10 h log each copy of
        the covariances is 130 MB). Nothing appends to it, so :meth:`arrays` returns views."""
        track = cls(float(t[0]), x[0], P[0])
        track._t, track._x, track._P = (np.asarray(a, dtype=float) for a in (t, x, P))
        track._n = len(track._t)
        track._finished = True
        return track

    def __len__(self) -> int:
        """Absolute number of poses so far (forgotten ones included)."""
        return self._offset + self._n

    def append(self, t: float, x, P) -> None:
        """Add the pose after one more step (``x`` (>= 3,), ``P`` (>= 3, >= 3): first 3 used)."""
        if self._finished:
            raise RuntimeError("a finished offline track (Track.from_arrays) is not appended to")
        n = self._n
        if n == self._t.shape[0]:
            self._make_room()
            n = self._n
        self._t[n] = t
        self._x[n] = x[:3]
        self._P[n] = P[:3, :3]
        self._n = n + 1

    def _make_room(self) -> None:
        """Full: drop the forgotten rows (live mode) if that frees half, else double."""
        dead = self._dead - self._offset
        live = self._n - dead
        if dead > 0 and 2 * live <= self._t.shape[0]:
            for a in (self._t, self._x, self._P):
                a[:live] = a[dead : self._n]
            self._offset, self._n = self._dead, live
            return
        cap = 2 * self._t.shape[0]
        for name in ("_t", "_x", "_P"):
            old = getattr(self, name)
            new = np.empty((cap,) + old.shape[1:])
            new[: self._n] = old[: self._n]
            setattr(self, name, new)

    def truncate(self, n: int) -> None:
        """Keep the first ``n`` poses (absolute count), for a replay from there."""
        if n < self._offset:
            raise ValueError(f"pose {n} was already forgotten (first kept: {self._offset})")
        self._n = min(self._n, n - self._offset)

    def forget_before(self, n: int) -> None:
        """Live mode: poses before absolute index ``n`` are no longer needed.

        They are dropped when the blocks are full (:meth:`append`), so the blocks stay at
        about twice the late window and each pose is copied a bounded number of times.
        """
        if not self.keep_all:
            self._dead = max(self._dead, min(n, len(self)))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kept times, poses and covariances: copies while the track can still change (a
        live track rewrites poses when late readings replay), views of a finished one."""
        n = self._n
        if self._finished:
            return self._t[:n], self._x[:n], self._P[:n]
        return self._t[:n].copy(), self._x[:n].copy(), self._P[:n].copy()

    def nbytes(self) -> int:
        """Bytes held by the blocks (for the memory benchmark)."""
        return self._t.nbytes + self._x.nbytes + self._P.nbytes


class Step(NamedTuple):
    """One processed odometry step, kept while it is inside the late window.

    ``backend`` is the filter backend's snapshot before the step, ``book`` the Localizer's
    bookkeeping then (counts, clone times, monitor lengths; shared between steps while it does
    not change), ``due`` the measurements applied inside the step and ``n_traj`` the track
    length before it. A named tuple: one is made per step, and that is cheaper than a frozen
    dataclass.
    """

    t0: float
    t1: float
    u: np.ndarray
    backend: object
    book: tuple
    due: tuple
    n_traj: int


class Steps:
    """The steps of the last ``late_window`` seconds (plus the one straddling its start)."""

    def __init__(self, late_window: float) -> None:
        self.late_window = float(late_window)
        self._steps: deque[Step] = deque()

    def __len__(self) -> int:
        return len(self._steps)

    def __bool__(self) -> bool:
        return bool(self._steps)

    def first(self) -> Step:
        return self._steps[0]

    def push(self, step: Step) -> None:
        """Add a step and forget those that no reading inside the window can reach."""
        steps = self._steps
        steps.append(step)
        horizon = step.t1 - self.late_window
        while len(steps) > 1 and steps[1].t0 < horizon:
            steps.popleft()

    def rebook(self, update) -> None:
        """Replace every step's ``book`` by ``update(book)`` (once per shared book)."""
        new: dict[int, tuple] = {}
        for i, step in enumerate(self._steps):
            key = id(step.book)
            if key not in new:
                new[key] = update(step.book)
            self._steps[i] = step._replace(book=new[key])

    def books(self) -> list[tuple]:
        """The steps' bookkeeping snapshots, oldest first."""
        return [step.book for step in self._steps]

    def cut(self, t: float) -> list[Step]:
        """Remove and return the steps from the one covering time ``t`` (``t1 >= t``) on.

        The search runs from the newest step backwards: a late reading is usually recent.
        """
        steps = self._steps
        out: list[Step] = []
        while steps and steps[-1].t1 >= t:
            out.append(steps.pop())
        out.reverse()
        return out


# ----------------------------------------------------------------------------- gyro rates
def keep_rate_sample(samples: list, t: float, wz: float, horizon: float) -> None:
    """Insert ``(t, wz)`` into the time-sorted ``samples``; forget those before ``horizon``.

    The samples that can still matter for a replay stay, plus the last one before them (its
    rate is held into the window).
    """
    bisect.insort(samples, (t, wz))
    while len(samples) > 2 and samples[1][0] < horizon:
        samples.pop(0)


def held_rate_integral(samples: list, t0: float, t1: float) -> float | None:
    """Integral over ``(t0, t1]`` of the rates ``samples`` = ``[(t, rate), ...]`` held
    (zero-order hold) until the next sample; None before the first sample.

    Before the first sample its rate is held backwards (no gap at the start of a log).
    """
    g = samples
    if not g or g[0][0] > t1:
        return None
    total, cursor = 0.0, t0
    i = bisect.bisect_right(g, (t0, math.inf)) - 1  # last sample at or before t0
    rate = g[i][1] if i >= 0 else g[0][1]
    for tj, wj in g[i + 1 :]:
        if tj > t1:
            break
        total += rate * (tj - cursor)
        cursor, rate = tj, wj
    return total + rate * (t1 - cursor)
