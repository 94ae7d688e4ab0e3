"""Encoder ticks and stepper steps -> wheel angles; counter rollover unwrapping.

The arithmetic of the lecture notes ``002_88fc37db58155723.txt``::

    48 ticks / motor rev x 20.4 motor revs / wheel rev x 1 wheel rev / (pi D) m

gives ticks per metre (3896.11 for D = 0.08 m; the 3246.76 printed beside it is the value
for D = 0.096 m, see ``docs/drives.md``). Modern Robotics 13.4 (``000_96a7e9c96987202e.txt``)
notes that stepper-driven wheels are "measured" by the commanded steps.

Angles are in radians; a "rev" is one full turn (2 pi rad).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Encoder",
    "steps_to_angle",
    "ticks_per_metre",
    "ticks_to_angle",
    "unwrap_rollover",
]


def _positive(value, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"'{key}' must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"'{key}' must be positive and finite, got {value!r}")
    return value


def ticks_to_angle(ticks, ticks_per_rev, gear_ratio=1.0) -> np.ndarray:
    """Wheel angle of an encoder count.

    Parameters
    ----------
    ticks : array_like
        Encoder counts (any shape).
    ticks_per_rev : float
        Ticks per revolution of the encoder shaft (the motor when ``gear_ratio != 1``).
    gear_ratio : float, optional
        Encoder-shaft revolutions per wheel revolution (002 source: 20.4 motor revs per wheel
        rev); 1 when the encoder sits on the wheel or ``ticks_per_rev`` is already per wheel rev.

    Returns
    -------
    ndarray
        ``2 pi ticks / (ticks_per_rev gear_ratio)``, rad, same shape as ``ticks``.
    """
    tpr = _positive(ticks_per_rev, "ticks_per_rev")
    gear = _positive(gear_ratio, "gear_ratio")
    return 2.0 * np.pi * np.asarray(ticks, dtype=float) / (tpr * gear)


def ticks_per_metre(ticks_per_motor_rev, gear_ratio, wheel_diameter) -> float:
    """Ticks per metre of wheel travel (002 source).

    ``ticks_per_motor_rev * gear_ratio / (pi * wheel_diameter)``; e.g. 48 ticks, 20.4 gear,
    D = 0.08 m -> 3896.11 ticks/m.

    Parameters
    ----------
    ticks_per_motor_rev : float
    gear_ratio : float
        Motor revolutions per wheel revolution.
    wheel_diameter : float
        m.

    Returns
    -------
    float
        ticks per metre.
    """
    tpr = _positive(ticks_per_motor_rev, "ticks_per_motor_rev")
    gear = _positive(gear_ratio, "gear_ratio")
    diam = _positive(wheel_diameter, "wheel_diameter")
    return tpr * gear / (np.pi * diam)


def steps_to_angle(steps, steps_per_rev, microsteps=1) -> np.ndarray:
    """Wheel angle of commanded stepper-motor steps (Modern Robotics 13.4).

    Parameters
    ----------
    steps : array_like
        Commanded (micro)steps.
    steps_per_rev : float
        Full steps per revolution (e.g. 200 for a 1.8 degree motor).
    microsteps : int, optional
        Microsteps per full step.

    Returns
    -------
    ndarray
        ``2 pi steps / (steps_per_rev microsteps)``, rad.
    """
    spr = _positive(steps_per_rev, "steps_per_rev")
    micro = _positive(microsteps, "microsteps")
    return 2.0 * np.pi * np.asarray(steps, dtype=float) / (spr * micro)


def unwrap_rollover(counts, rollover) -> tuple[np.ndarray, int]:
    """Undo the wrap-around of a hardware counter.

    A counter of ``rollover`` states (e.g. 65536 for 16 bit) wraps from its top back to its
    bottom (or the other way when counting down). Between consecutive samples a jump of more
    than ``rollover / 2`` in magnitude cannot be real motion (the wheel would have to turn more
    than half the counter range in one sample), so it is counted as a wrap and
    ``-+rollover`` is added from that sample on. Works for unsigned (``0 .. rollover-1``) and
    signed (``-rollover/2 .. rollover/2 - 1``) counters alike.

    Parameters
    ----------
    counts : array_like, shape (N,) or (N, C)
        Raw counter values, time along axis 0 (one column per wheel).
    rollover : int or float
        Number of counter states (the period of the wrap), > 0.

    Returns
    -------
    unwrapped : ndarray, shape like ``counts``
        Continuous counts (int64 for integer input, float64 otherwise); the first sample is
        unchanged.
    n_wraps : int
        Number of wraps found (both directions, all columns), for the repair counters.

    Raises
    ------
    ValueError
        For a non-positive ``rollover``, non-finite counts or a shape other than 1-D/2-D.
    """
    period = _positive(rollover, "rollover")
    raw = np.asarray(counts)
    if raw.ndim not in (1, 2):
        raise ValueError(f"counts must have shape (N,) or (N, C), got {raw.shape}")
    is_int = np.issubdtype(raw.dtype, np.integer) and float(period).is_integer()
    c = raw.astype(np.int64) if is_int else raw.astype(float)
    if not is_int and not np.isfinite(c).all():
        idx = np.argwhere(~np.isfinite(c))[0]
        raise ValueError(f"counts: non-finite value at index {tuple(int(i) for i in idx)}")
    if c.shape[0] < 2:
        return c.copy(), 0
    step = np.diff(c, axis=0)
    half = 0.5 * period
    # forward wrap: top -> bottom looks like a large negative jump; backward the opposite
    wraps = (step < -half).astype(np.int64) - (step > half).astype(np.int64)
    n_wraps = int(np.count_nonzero(wraps))
    if n_wraps == 0:
        return c.copy(), 0
    offset = np.cumsum(wraps, axis=0)
    offset = np.concatenate([np.zeros_like(offset[:1]), offset], axis=0)
    if is_int:
        return c + offset * int(period), n_wraps
    return c + offset * period, n_wraps


@dataclass(frozen=True)
class Encoder:
    """A wheel encoder: ticks per revolution, gear ratio and optional counter rollover.

    Parameters
    ----------
    ticks_per_rev : float
        Ticks per encoder-shaft revolution (may be fractional when it already includes a
        gear, e.g. 48 x 20.4 = 979.2 ticks per wheel revolution).
    gear_ratio : float, optional
        Encoder-shaft revolutions per wheel revolution.
    rollover : int, optional
        Counter period (e.g. 65536); ``None`` for counters that never wrap.
    """

    ticks_per_rev: float
    gear_ratio: float = 1.0
    rollover: int | float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "ticks_per_rev", _positive(self.ticks_per_rev, "ticks_per_rev"))
        object.__setattr__(self, "gear_ratio", _positive(self.gear_ratio, "gear_ratio"))
        if self.rollover is not None:
            _positive(self.rollover, "rollover")

    def convert(self, counts) -> tuple[np.ndarray, int]:
        """Cumulative wheel angles (rad) and the number of rollovers repaired.

        Parameters
        ----------
        counts : array_like, shape (N,) or (N, C)
            Raw cumulative counter readings, time along axis 0.

        Returns
        -------
        angles : ndarray, float, same shape
        n_wraps : int
        """
        if self.rollover is None:
            c, n = np.asarray(counts), 0
        else:
            c, n = unwrap_rollover(counts, self.rollover)
        return ticks_to_angle(c, self.ticks_per_rev, self.gear_ratio), n

    def to_radians(self, counts) -> np.ndarray:
        """Cumulative wheel angles in rad (rollover unwrapped when ``rollover`` is set)."""
        return self.convert(counts)[0]

    def ticks_per_metre(self, wheel_diameter: float) -> float:
        """Ticks per metre of travel for a wheel of ``wheel_diameter`` m."""
        return ticks_per_metre(self.ticks_per_rev, self.gear_ratio, wheel_diameter)
