"""Wheels on two sides: the differential drive and the skid-steer (tracked) drive.

Both are linear, ``twist = F u`` (Modern Robotics eq. 13.34; Politecnico slides ``003_...``
for the skid-steer ICR kinematics).

``wheels_per_side = n > 1`` (a six-wheeled rover, a four-wheeled skid steer with an encoder on
every wheel): the inputs are ``left1 .. leftn, right1 .. rightn`` and each side's travel is
the mean of its wheels, the maximum-likelihood estimate for equal, independent wheel noise
(each column of the two-wheel ``F`` divided by ``n`` and repeated ``n`` times). The error model
then sees every wheel, so a side's variance falls as ``1/n``; ``input_groups`` names the side
mates for the disagreement check of :func:`odofuse.motion.side_outliers`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from odofuse.drives.base import _check_positive, _check_real, _LinearDrive
from odofuse.errors import ConfigError


class _TwoSided(_LinearDrive):
    """Left and right wheel sets, ``wheels_per_side`` wheels each (see the module docstring)."""

    wheels_per_side: int
    degree_of_mobility: ClassVar[int] = 2

    def _check_sides(self) -> None:
        n = self.wheels_per_side
        if isinstance(n, bool) or not isinstance(n, (int, float, np.integer, np.floating)):
            raise ConfigError(
                f"{type(self).__name__}: wheels_per_side must be a whole number, got {n!r}",
                key="wheels_per_side",
            )
        if not (math.isfinite(n) and n >= 1 and float(n) == int(n)):
            raise ConfigError(
                f"{type(self).__name__}: wheels_per_side must be a whole number >= 1, got {n!r}",
                key="wheels_per_side",
            )
        object.__setattr__(self, "wheels_per_side", int(n))

    def side_matrix(self) -> np.ndarray:
        """``F`` of one wheel per side, ``(3, 2)`` over ``(left, right)``."""
        raise NotImplementedError

    @property
    def sides(self) -> tuple[str, ...]:
        """``"left"`` or ``"right"`` for each input."""
        n = self.wheels_per_side
        return ("left",) * n + ("right",) * n

    @property
    def input_names(self) -> tuple[str, ...]:  # type: ignore[override]
        n = self.wheels_per_side
        if n == 1:
            return ("left", "right")
        return tuple(f"{side}{i + 1}" for side in ("left", "right") for i in range(n))

    @property
    def input_kinds(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("wheel",) * (2 * self.wheels_per_side)

    @property
    def input_groups(self) -> tuple[tuple[int, ...], ...]:
        """Indices of the left wheels and of the right wheels."""
        n = self.wheels_per_side
        return (tuple(range(n)), tuple(range(n, 2 * n)))

    def matrix(self) -> np.ndarray:
        n = self.wheels_per_side
        return np.repeat(self.side_matrix() / n, n, axis=1)

    def travel_scale(self) -> np.ndarray:
        return np.repeat([self.wheel_radius_left, self.wheel_radius_right], self.wheels_per_side)


@dataclass(frozen=True)
class Differential(_TwoSided):
    r"""Differential drive (or the two rear wheels of a car), Modern Robotics eq. 13.34.

    .. math::

        \mathcal V_b = r \begin{bmatrix} -1/(2d) & 1/(2d) \\ 1/2 & 1/2 \\ 0 & 0
        \end{bmatrix} \begin{bmatrix} \Delta\theta_L \\ \Delta\theta_R \end{bmatrix}

    with ``2 d = track_width`` (``000_96a7e9c96987202e.txt``); with different wheel radii
    ``r`` multiplies each column by that wheel's radius.

    Parameters
    ----------
    wheel_radius : float
        m.
    track_width : float
        Distance between the left and right wheel contact points, m (2d).
    wheel_radius_left, wheel_radius_right : float, optional
        Per-wheel radii in m (default ``wheel_radius``), e.g. from a UMBmark calibration.
    wheels_per_side : int, optional
        Encoded wheels on each side (default 1); see the module docstring.
    """

    wheel_radius: float
    track_width: float
    wheel_radius_left: float | None = None
    wheel_radius_right: float | None = None
    wheels_per_side: int = 1

    name: ClassVar[str] = "differential"

    def __post_init__(self) -> None:
        self._check_sides()
        for side in ("wheel_radius_left", "wheel_radius_right"):
            if getattr(self, side) is None:
                object.__setattr__(self, side, self.wheel_radius)
        _check_positive(
            self, "wheel_radius", "track_width", "wheel_radius_left", "wheel_radius_right"
        )

    def side_matrix(self) -> np.ndarray:
        rl, rr, d = self.wheel_radius_left, self.wheel_radius_right, 0.5 * self.track_width
        return np.array([[-rl / (2 * d), rr / (2 * d)], [rl / 2, rr / 2], [0.0, 0.0]])


@dataclass(frozen=True)
class SkidSteer(_TwoSided):
    r"""Skid-steer (tracked) drive with ICR kinematics, Politecnico slides (``003_...``).

    The slides give, on the track speeds ``(omega_l r, omega_r r)``,

    .. math::

        \begin{bmatrix} v_x \\ v_y \\ \omega_z \end{bmatrix}
        = \frac{1}{y_l - y_r}\begin{bmatrix} -y_r & y_l \\ x_G & -x_G \\ -1 & 1
        \end{bmatrix}\begin{bmatrix} \omega_l r \\ \omega_r r \end{bmatrix}

    where ``y_l``/``y_r`` are the lateral coordinates (y to the left, as in our body frame:
    ``y_l = (v_x - omega_l r) / omega_z``) of the left/right tread ICRs and ``x_G`` the
    longitudinal ICR coordinate (``x_G = -v_y / omega_z``). We return the rows reordered to
    ``[omega, v_x, v_y]``. With ``y_l = -y_r = B/2`` and ``x_G = 0`` this is exactly
    :class:`Differential` (Modern Robotics 13.34). The expansion factor is
    ``chi = (y_l - y_r) / B >= 1``.

    Parameters
    ----------
    wheel_radius : float
        Sprocket / wheel radius, m.
    track_width : float
        B, distance between the tread centre lines, m.
    y_l, y_r : float, optional
        Tread ICR lateral coordinates, m; default ``+B/2`` and ``-B/2``.
    x_G : float, optional
        Longitudinal ICR coordinate, m (default 0, ICR level with the body origin).
    wheel_radius_left, wheel_radius_right : float, optional
        Per-side radii, m (default ``wheel_radius``).
    wheels_per_side : int, optional
        Encoded wheels on each side (default 1); see the module docstring.
    """

    wheel_radius: float
    track_width: float
    y_l: float | None = None
    y_r: float | None = None
    x_G: float = 0.0
    wheel_radius_left: float | None = None
    wheel_radius_right: float | None = None
    wheels_per_side: int = 1

    name: ClassVar[str] = "skid_steer"

    def __post_init__(self) -> None:
        self._check_sides()
        _check_positive(self, "wheel_radius", "track_width")
        for side in ("wheel_radius_left", "wheel_radius_right"):
            if getattr(self, side) is None:
                object.__setattr__(self, side, self.wheel_radius)
        _check_positive(self, "wheel_radius_left", "wheel_radius_right")
        if self.y_l is None:
            object.__setattr__(self, "y_l", 0.5 * self.track_width)
        if self.y_r is None:
            object.__setattr__(self, "y_r", -0.5 * self.track_width)
        for key in ("y_l", "y_r", "x_G"):
            _check_real(self, key)
        if not self.y_l > self.y_r:
            raise ConfigError(
                f"SkidSteer: need y_l > y_r, got y_l={self.y_l}, y_r={self.y_r}", key="y_l"
            )
        if self.chi < 1.0 - 1e-12:
            raise ConfigError(
                f"SkidSteer: expansion factor chi = (y_l - y_r) / B must be >= 1 "
                f"(Politecnico slides 003), got {self.chi}",
                key="y_l",
            )

    @classmethod
    def from_chi(cls, wheel_radius: float, track_width: float, chi: float, x_G: float = 0.0):
        """Symmetric skid steer with ``y_l = -y_r = chi B / 2`` (slides: ``chi = 2 y0 / B``)."""
        if isinstance(chi, bool) or not isinstance(chi, (int, float, np.integer, np.floating)):
            raise ConfigError(f"SkidSteer: chi must be a number, got {chi!r}", key="chi")
        if not (math.isfinite(chi) and chi >= 1.0):
            raise ConfigError(f"SkidSteer: chi must be >= 1, got {chi!r}", key="chi")
        if isinstance(track_width, (int, float)) and not isinstance(track_width, bool):
            y0 = 0.5 * float(chi) * float(track_width)
        else:
            y0 = None  # let __post_init__ report the bad track_width
        return cls(wheel_radius, track_width, y_l=y0, y_r=None if y0 is None else -y0, x_G=x_G)

    @property
    def chi(self) -> float:
        """Expansion factor ``(y_l - y_r) / B`` (Politecnico slides ``003_...``), >= 1."""
        return (self.y_l - self.y_r) / self.track_width

    def side_matrix(self) -> np.ndarray:
        rl, rr = self.wheel_radius_left, self.wheel_radius_right
        yl, yr, xg = self.y_l, self.y_r, self.x_G
        J_omega = np.array([[-yr, yl], [xg, -xg], [-1.0, 1.0]]) / (
            yl - yr
        )  # slides' rows vx, vy, wz
        return J_omega[[2, 0, 1]] * np.array([rl, rr])
