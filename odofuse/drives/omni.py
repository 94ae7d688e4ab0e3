"""Holonomic wheel sets: three omniwheels, four mecanum wheels and any generic layout.

All are linear, ``twist = F u`` with ``F = pinv(H(0))`` (Modern Robotics 13.2, eqs.
13.5, 13.8, 13.32, 13.33).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from odofuse.drives.base import _check_positive, _LinearDrive
from odofuse.errors import ConfigError


@dataclass(frozen=True)
class Omni3(_LinearDrive):
    r"""Three-omniwheel robot, exactly Modern Robotics eq. 13.32 (``000_...``).

    .. math::

        \mathcal V_b = r \begin{bmatrix} -1/(3d) & -1/(3d) & -1/(3d) \\
        2/3 & -1/3 & -1/3 \\ 0 & -1/(2\sin(\pi/3)) & 1/(2\sin(\pi/3)) \end{bmatrix}
        \Delta\theta

    MR numbering: wheel 1 at ``(0, d)`` driving along +x, wheels 2 and 3 at
    ``(d sqrt(3)/2, -d/2)`` and ``(-d sqrt(3)/2, -d/2)`` driving at 240 and 120 degrees
    (the layout whose H(0) is MR eq. 13.9). ``docs/drives.md`` maps the Politecnico
    slides' matrix onto this one.

    Parameters
    ----------
    wheel_radius : float
        r, m.
    wheel_distance : float
        d, centre of the robot to each wheel, m.
    """

    wheel_radius: float
    wheel_distance: float

    name: ClassVar[str] = "omni3"
    input_names: ClassVar[tuple[str, ...]] = ("w1", "w2", "w3")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel",) * 3
    degree_of_mobility: ClassVar[int] = 3

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheel_distance")

    def matrix(self) -> np.ndarray:
        r, d = self.wheel_radius, self.wheel_distance
        s = 1.0 / (2.0 * math.sin(math.pi / 3.0))
        return r * np.array(
            [[-1 / (3 * d)] * 3, [2 / 3, -1 / 3, -1 / 3], [0.0, -s, s]],
        )

    def travel_scale(self) -> np.ndarray:
        return np.full(3, self.wheel_radius)


@dataclass(frozen=True)
class Mecanum4(_LinearDrive):
    r"""Four-mecanum-wheel robot, exactly Modern Robotics eq. 13.33 (``000_...``).

    .. math::

        \mathcal V_b = \frac r4 \begin{bmatrix}
        -1/(\ell+w) & 1/(\ell+w) & 1/(\ell+w) & -1/(\ell+w) \\
        1 & 1 & 1 & 1 \\ -1 & 1 & -1 & 1 \end{bmatrix} \Delta\theta

    MR numbering: 1 front-left ``(l, w)``, 2 front-right ``(l, -w)``, 3 rear-right
    ``(-l, -w)``, 4 rear-left ``(-l, w)``; free-roller angles ``gamma = -pi/4, pi/4,
    -pi/4, pi/4``; all driving directions along +x.

    Parameters
    ----------
    wheel_radius : float
        r, m.
    half_length : float
        l, half the front-rear wheel distance, m.
    half_width : float
        w, half the left-right wheel distance, m.
    """

    wheel_radius: float
    half_length: float
    half_width: float

    name: ClassVar[str] = "mecanum4"
    input_names: ClassVar[tuple[str, ...]] = ("w1", "w2", "w3", "w4")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel",) * 4
    degree_of_mobility: ClassVar[int] = 3

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "half_length", "half_width")

    def matrix(self) -> np.ndarray:
        k = 1.0 / (self.half_length + self.half_width)
        return (self.wheel_radius / 4.0) * np.array(
            [[-k, k, k, -k], [1.0, 1.0, 1.0, 1.0], [-1.0, 1.0, -1.0, 1.0]]
        )

    def travel_scale(self) -> np.ndarray:
        return np.full(4, self.wheel_radius)


@dataclass(frozen=True)
class Generic(_LinearDrive):
    r"""Any set of omni / mecanum / fixed wheels: ``F = pinv(H(0))``, Modern Robotics 13.2/13.4.

    Row ``i`` of ``H(0)`` (MR eq. 13.5 at phi = 0, used in eq. 13.8 ``Delta theta = H(0) V_b``):

    .. math::

        h_i(0) = \frac{1}{r_i\cos\gamma_i}\big[x_i\sin(\beta_i+\gamma_i)
        - y_i\cos(\beta_i+\gamma_i),\ \cos(\beta_i+\gamma_i),\ \sin(\beta_i+\gamma_i)\big]

    and ``F = pinv(H(0))``. A conventional fixed wheel is ``gamma = 0`` (its no-slip
    constraint is then *not* enforced, the pseudo-inverse just ignores the unobservable
    direction: two fixed wheels on a common axle give MR eq. 13.34 exactly).

    Parameters
    ----------
    wheel_radius : float or sequence of float
        r_i, m (one value for all wheels or one per wheel).
    positions : sequence of (x_i, y_i)
        Wheel contact points in the body frame, m.
    driving_angles : sequence of float
        beta_i, driving direction of each wheel, rad from the body x axis.
    roller_angles : sequence of float
        gamma_i, free-roller angle, rad (0 omniwheel/fixed, +-pi/4 mecanum); ``|gamma| < pi/2``.
    names : sequence of str, optional
        Input names; default ``w1 .. wn``.
    """

    wheel_radius: Any
    positions: Any
    driving_angles: Any
    roller_angles: Any
    names: Any = None

    name: ClassVar[str] = "generic"

    def __post_init__(self) -> None:
        def arr(key):
            try:
                a = np.asarray(getattr(self, key), dtype=float)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"Generic: {key} must be numeric ({exc})", key=key) from None
            return a

        pos = arr("positions")
        if pos.ndim != 2 or pos.shape[1] != 2 or pos.shape[0] < 1:
            raise ConfigError(
                f"Generic: positions must have shape (n, 2), got {pos.shape}", key="positions"
            )
        n = pos.shape[0]
        beta = arr("driving_angles")
        gamma = arr("roller_angles")
        for key, a in (("driving_angles", beta), ("roller_angles", gamma)):
            if a.shape != (n,):
                raise ConfigError(f"Generic: {key} must have shape ({n},), got {a.shape}", key=key)
        r = arr("wheel_radius")
        if r.ndim == 0:
            r = np.full(n, float(r))
        if r.shape != (n,):
            raise ConfigError(
                f"Generic: wheel_radius must be a number or have shape ({n},)", key="wheel_radius"
            )
        for key, a in (
            ("positions", pos),
            ("driving_angles", beta),
            ("roller_angles", gamma),
            ("wheel_radius", r),
        ):
            if not np.isfinite(a).all():
                raise ConfigError("Generic: values must be finite", key=key)
        if not (r > 0).all():
            raise ConfigError("Generic: wheel radii must be positive", key="wheel_radius")
        if not (np.abs(gamma) < 0.5 * np.pi - 1e-9).all():
            raise ConfigError("Generic: |roller angle| must be < pi/2", key="roller_angles")
        names = tuple(f"w{i + 1}" for i in range(n)) if self.names is None else tuple(self.names)
        if len(names) != n or len(set(names)) != n or not all(isinstance(s, str) for s in names):
            raise ConfigError(f"Generic: names must be {n} distinct strings", key="names")
        object.__setattr__(self, "wheel_radius", tuple(r.tolist()))
        object.__setattr__(self, "positions", tuple(map(tuple, pos.tolist())))
        object.__setattr__(self, "driving_angles", tuple(beta.tolist()))
        object.__setattr__(self, "roller_angles", tuple(gamma.tolist()))
        object.__setattr__(self, "names", names)

    @property
    def input_names(self) -> tuple[str, ...]:  # type: ignore[override]
        return self.names

    @property
    def input_kinds(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("wheel",) * len(self.names)

    @property
    def degree_of_mobility(self) -> int:  # type: ignore[override]
        """``rank F``: the dimension of the twists reachable by changing wheel speeds."""
        return int(np.linalg.matrix_rank(self.H0()))

    def H0(self) -> np.ndarray:
        """``H(0)``, shape ``(n, 3)``: wheel speeds (rad) = ``H(0)`` body twist (MR eq. 13.8)."""
        pos = np.asarray(self.positions)
        r = np.asarray(self.wheel_radius)
        beta = np.asarray(self.driving_angles)
        gamma = np.asarray(self.roller_angles)
        bg = beta + gamma
        x, y = pos[:, 0], pos[:, 1]
        rows = np.stack([x * np.sin(bg) - y * np.cos(bg), np.cos(bg), np.sin(bg)], axis=1)
        return rows / (r * np.cos(gamma))[:, None]

    def matrix(self) -> np.ndarray:
        # pinv (SVD) rather than (H^T H)^-1 H^T: it also covers rank-deficient layouts
        # such as the diff drive, whose lateral velocity is unobservable.
        return np.linalg.pinv(self.H0())

    def travel_scale(self) -> np.ndarray:
        return np.asarray(self.wheel_radius, dtype=float)
