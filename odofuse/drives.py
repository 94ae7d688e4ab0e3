"""Drive models: wheel readings -> body twist, its Jacobian, inverse kinematics and ICR.

Every drive is a frozen dataclass holding geometry only and satisfying the ``DriveModel``
protocol of ``docs/architecture.md``:

* ``twist(u)``: one step of drive input ``u`` -> body twist ``[omega, v_x, v_y]`` for a step
  of length Delta t = 1 (Modern Robotics 13.4, ``000_96a7e9c96987202e.txt``): omega in rad,
  v_x, v_y in metres, body frame at the start of the step (x forward, y left).
* ``u`` is ``(n,)`` or a batch ``(N, n)``: wheel angle increments in rad (in the order of
  ``input_names``) followed by steering angles in rad (the value held during the step).
* ``J_twist_u(u)`` is the analytic ``(3, n)`` (or ``(N, 3, n)``) Jacobian.
* ``travel(u)`` = ``|u| * travel_scale()`` are the metres rolled by each input's wheel
  (0 for steering angles), the ``|ds_i|`` of the odometry error model.
* ``inverse(twist)`` returns inputs producing ``twist`` (raises ``ValueError`` when the
  drive cannot produce it, e.g. ``v_y != 0`` on a nonholonomic drive).
* ``icr(twist)`` is the instantaneous centre of rotation in the body frame.

Extra class attributes (an extension of the contract): ``input_kinds`` says for each
input whether it is a cumulative wheel angle (``"wheel"``, differenced from ``wheels.csv``),
a steering angle held during the step (``"steer"``, taken as is), a cumulative steering
encoder (``"steer_increment"``, differenced) or an increment read from ``odometry.csv``
(``"increment"``); ``degree_of_mobility`` and ``degree_of_steerability`` are Siegwart's
delta_m and delta_s (``004_f4547100a083f338.txt``; see ``docs/drives.md`` for the derivation).

The drives and their sources:

========================  ===========================================================
:class:`Differential`     Modern Robotics eq. 13.34 (``000_...``)
:class:`SkidSteer`        ICR kinematics of the Politecnico slides (``003_...``)
:class:`Tricycle`         Politecnico slides (``003_...``)
:class:`Ackermann`        Politecnico slides (``003_...``), least-squares fusion
:class:`Bicycle`          Politecnico slides' bicycle approximation (``003_...``)
:class:`Synchro`          Politecnico slides (``003_...``)
:class:`Omni3`            Modern Robotics eq. 13.32 (``000_...``)
:class:`Mecanum4`         Modern Robotics eq. 13.33 (``000_...``)
:class:`Generic`          Modern Robotics eq. 13.5 / 13.8, F = pinv(H(0))
:class:`Increments`       ``odometry.csv`` (ds, dtheta), the Plaza ``DR`` stream
========================  ===========================================================
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from odofuse.errors import ConfigError
from odofuse.se2 import wrap

__all__ = [
    "DRIVES",
    "Ackermann",
    "Bicycle",
    "Differential",
    "Generic",
    "Increments",
    "Mecanum4",
    "Omni3",
    "SkidSteer",
    "Synchro",
    "Tricycle",
    "icr",
    "make_drive",
    "turn_drive_turn",
]

# Relative tolerance of the "is this twist reachable" test in the inverse kinematics.
_REACH_TOL = 1e-9


# --------------------------------------------------------------------------- helpers
def _as_batch(x, n: int, what: str, names: Sequence[str]) -> tuple[np.ndarray, bool]:
    """Return ``x`` as a float ``(N, n)`` array and whether it was a single ``(n,)`` row."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 1 and a.shape[0] == n:
        single = True
        a = a[None, :]
    elif a.ndim == 2 and a.shape[1] == n:
        single = False
    else:
        raise ValueError(
            f"{what}: expected shape ({n},) or (N, {n}) for {tuple(names)}, got {a.shape}"
        )
    if not np.isfinite(a).all():
        row, col = np.argwhere(~np.isfinite(a))[0]
        raise ValueError(f"{what}: non-finite value in row {row}, column '{names[col]}'")
    return a, single


def _twists(twist, what: str) -> tuple[np.ndarray, bool]:
    return _as_batch(twist, 3, what, ("omega", "v_x", "v_y"))


def _out(a: np.ndarray, single: bool) -> np.ndarray:
    return a[0] if single else a


def _check_positive(obj, *names: str) -> None:
    """Validate and convert the named geometry fields to positive finite floats."""
    for key in names:
        val = getattr(obj, key)
        if isinstance(val, bool) or not isinstance(val, (int, float, np.integer, np.floating)):
            raise ConfigError(
                f"{type(obj).__name__}: geometry value must be a number, got {val!r}", key=key
            )
        val = float(val)
        if not (math.isfinite(val) and val > 0.0):
            raise ConfigError(
                f"{type(obj).__name__}: geometry value must be positive and finite, got {val!r}",
                key=key,
            )
        object.__setattr__(obj, key, val)


def _check_real(obj, key: str) -> None:
    val = getattr(obj, key)
    if isinstance(val, bool) or not isinstance(val, (int, float, np.integer, np.floating)):
        raise ConfigError(
            f"{type(obj).__name__}: geometry value must be a number, got {val!r}", key=key
        )
    if not math.isfinite(float(val)):
        raise ConfigError(
            f"{type(obj).__name__}: geometry value must be finite, got {val!r}", key=key
        )
    object.__setattr__(obj, key, float(val))


def icr(twist) -> np.ndarray:
    """Instantaneous centre of rotation of a body twist, in the body frame.

    A rigid body with twist ``[omega, v_x, v_y]`` has zero velocity at the point
    ``p`` with ``v + omega * e_z x p = 0``, i.e. ``p = (-v_y / omega, v_x / omega)``
    (Politecnico slides ``003_...``: ICC at distance ``R = V / omega`` to the left;
    Siegwart ``004_...``).

    Parameters
    ----------
    twist : array_like, shape (3,) or (N, 3)
        Body twist ``[omega, v_x, v_y]`` (rad, m, m per step).

    Returns
    -------
    ndarray, shape (2,) or (N, 2)
        ICR ``[x, y]`` in metres, body frame; ``[inf, inf]`` where ``omega == 0``
        (pure translation or standstill).
    """
    T, single = _twists(twist, "icr")
    out = np.full((T.shape[0], 2), np.inf)
    w = T[:, 0]
    nz = w != 0.0
    out[nz, 0] = -T[nz, 2] / w[nz]
    out[nz, 1] = T[nz, 1] / w[nz]
    return _out(out, single)


def _unreachable(bad: np.ndarray, resid: np.ndarray, name: str, why: str) -> None:
    if bad.any():
        row = int(np.argmax(bad))
        raise ValueError(
            f"{name}.inverse: twist row {row} cannot be produced by this drive ({why}); "
            f"residual {resid[row]:.3g}"
        )


# --------------------------------------------------------------------------- base classes
class _Drive:
    """Shared behaviour: travel from the scale, ICR, input checks."""

    name: ClassVar[str]
    input_names: ClassVar[tuple[str, ...]]
    input_kinds: ClassVar[tuple[str, ...]]
    degree_of_mobility: ClassVar[int]
    degree_of_steerability: ClassVar[int] = 0

    def _u(self, u) -> tuple[np.ndarray, bool]:
        names = self.input_names
        return _as_batch(u, len(names), f"{type(self).__name__}", names)

    def travel_scale(self) -> np.ndarray:
        """``(n,)`` d travel_i / d u_i: metres per radian of wheel angle (0 for steering)."""
        raise NotImplementedError

    def travel(self, u) -> np.ndarray:
        """Metres rolled by each input's wheel, ``|u_i| * travel_scale_i``.

        Parameters
        ----------
        u : array_like, shape (n,) or (N, n)

        Returns
        -------
        ndarray, shape (n,) or (N, n)
            Non-negative; 0 for steering-angle inputs.
        """
        U, single = self._u(u)
        return _out(np.abs(U) * self.travel_scale(), single)

    def icr(self, twist) -> np.ndarray:
        """ICR of ``twist`` in the body frame, ``(2,)`` or ``(N, 2)``; see :func:`icr`."""
        return icr(twist)


class _LinearDrive(_Drive):
    """A drive whose twist is linear in the input, ``twist = F u`` (Modern Robotics 13.4)."""

    def matrix(self) -> np.ndarray:
        """``F`` of ``twist = F u``, shape ``(3, n)``."""
        raise NotImplementedError

    def twist(self, u) -> np.ndarray:
        """Body twist ``[omega, v_x, v_y]`` = ``F u``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        # (F @ U^T)^T: numpy's U @ F^T with a tall, 2-column U is ~40x slower here.
        return _out((self.matrix() @ U.T).T, single)

    def J_twist_u(self, u) -> np.ndarray:
        """Jacobian ``F`` (constant), ``(3, n)`` or ``(N, 3, n)``."""
        U, single = self._u(u)
        J = np.broadcast_to(self.matrix(), (U.shape[0], 3, U.shape[1])).copy()
        return _out(J, single)

    def inverse(self, twist) -> np.ndarray:
        """Inputs producing ``twist``: ``u = pinv(F) twist`` (for omni/mecanum this is H(0)).

        Raises
        ------
        ValueError
            If ``twist`` is not in the range of ``F`` (e.g. ``v_y != 0`` for a
            differential drive), naming the offending row.
        """
        T, single = _twists(twist, f"{type(self).__name__}.inverse")
        F = self.matrix()
        U = T @ np.linalg.pinv(F).T
        resid = np.linalg.norm(U @ F.T - T, axis=1)
        scale = 1.0 + np.linalg.norm(T, axis=1)
        _unreachable(
            resid > _REACH_TOL * scale, resid, type(self).__name__, "outside the range of F"
        )
        return _out(U, single)


# --------------------------------------------------------------------------- drives
@dataclass(frozen=True)
class Differential(_LinearDrive):
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
    """

    wheel_radius: float
    track_width: float
    wheel_radius_left: float | None = None
    wheel_radius_right: float | None = None

    name: ClassVar[str] = "differential"
    input_names: ClassVar[tuple[str, ...]] = ("left", "right")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "wheel")
    degree_of_mobility: ClassVar[int] = 2

    def __post_init__(self) -> None:
        for side in ("wheel_radius_left", "wheel_radius_right"):
            if getattr(self, side) is None:
                object.__setattr__(self, side, self.wheel_radius)
        _check_positive(
            self, "wheel_radius", "track_width", "wheel_radius_left", "wheel_radius_right"
        )

    def matrix(self) -> np.ndarray:
        rl, rr, d = self.wheel_radius_left, self.wheel_radius_right, 0.5 * self.track_width
        return np.array([[-rl / (2 * d), rr / (2 * d)], [rl / 2, rr / 2], [0.0, 0.0]])

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius_left, self.wheel_radius_right])


@dataclass(frozen=True)
class SkidSteer(_LinearDrive):
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
    """

    wheel_radius: float
    track_width: float
    y_l: float | None = None
    y_r: float | None = None
    x_G: float = 0.0
    wheel_radius_left: float | None = None
    wheel_radius_right: float | None = None

    name: ClassVar[str] = "skid_steer"
    input_names: ClassVar[tuple[str, ...]] = ("left", "right")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "wheel")
    degree_of_mobility: ClassVar[int] = 2

    def __post_init__(self) -> None:
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

    def matrix(self) -> np.ndarray:
        rl, rr = self.wheel_radius_left, self.wheel_radius_right
        yl, yr, xg = self.y_l, self.y_r, self.x_G
        J_omega = np.array([[-yr, yl], [xg, -xg], [-1.0, 1.0]]) / (
            yl - yr
        )  # slides' rows vx, vy, wz
        return J_omega[[2, 0, 1]] * np.array([rl, rr])

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius_left, self.wheel_radius_right])


@dataclass(frozen=True)
class Synchro(_LinearDrive):
    """Synchronous drive, Politecnico slides (``003_...``): v and omega controlled directly.

    All wheels are driven by one motor and steered together by a second; the slides
    integrate it as ``x' = v cos(theta)``, ``y' = v sin(theta)``, ``theta' = omega`` with
    ``theta`` the (common) wheel direction. The body frame is therefore the steering
    (turret) frame, aligned with the wheels, and the inputs are

    * ``drive``: wheel angle increment, rad (``v_x = r * drive``),
    * ``steer``: increment of the steering motor angle over the step, rad (``omega = steer``).

    Both come from cumulative encoders (``input_kinds = ("wheel", "steer_increment")``):
    an absolute steering angle would carry no information in the turret frame (it is 0 by
    construction), the rotation over the step is what moves the frame. The steering increment
    is an odometric measurement in its own right, so its ``travel_scale`` is 1 (rad), like the
    ``dtheta`` of :class:`Increments`, and the error model can give it a variance.

    Parameters
    ----------
    wheel_radius : float
        m.
    """

    wheel_radius: float

    name: ClassVar[str] = "synchro"
    input_names: ClassVar[tuple[str, ...]] = ("drive", "steer")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "steer_increment")
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius")

    def matrix(self) -> np.ndarray:
        return np.array([[0.0, 1.0], [self.wheel_radius, 0.0], [0.0, 0.0]])

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius, 1.0])


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


@dataclass(frozen=True)
class Increments(_LinearDrive):
    """Odometry increments ``(ds, dtheta)`` from ``odometry.csv`` (Plaza ``DR`` form).

    ``twist = [dtheta, ds, 0]``: a unicycle step of arc length ``ds`` (m) turning by
    ``dtheta`` (rad), the "tips and tricks" form of the Politecnico slides (``003_...``:
    ``v T_s = Delta s``, ``omega T_s = Delta theta``). ``travel = (|ds|, |dtheta|)`` with
    scale ``(1, 1)``.
    """

    name: ClassVar[str] = "increments"
    input_names: ClassVar[tuple[str, ...]] = ("ds", "dtheta")
    input_kinds: ClassVar[tuple[str, ...]] = ("increment", "increment")
    degree_of_mobility: ClassVar[int] = 2

    def matrix(self) -> np.ndarray:
        return np.array([[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]])

    def travel_scale(self) -> np.ndarray:
        return np.ones(2)


def _steered_wheel_inverse(vx_w, vy_w):
    """Rolling speed and steering angle of a wheel whose contact point moves by ``(vx_w, vy_w)``.

    The steering angle is kept in ``(-pi/2, pi/2]`` and the rolling speed takes the sign of
    ``vx_w`` (a wheel that moves backwards rolls backwards rather than steering by pi).
    """
    s = np.where(vx_w < 0.0, -1.0, 1.0)
    delta = np.arctan2(s * vy_w, s * vx_w)
    speed = s * np.hypot(vx_w, vy_w)
    return speed, delta


def _nonholonomic_vy(T: np.ndarray, name: str) -> None:
    scale = 1.0 + np.linalg.norm(T, axis=1)
    resid = np.abs(T[:, 2])
    _unreachable(resid > _REACH_TOL * scale, resid, name, "v_y must be 0 at the rear axle")


@dataclass(frozen=True)
class Tricycle(_Drive):
    r"""Tricycle (AGV): one steered, driven front wheel; Politecnico slides (``003_...``).

    Body frame at the midpoint of the passive rear axle; the steered wheel is ``d``
    ahead of it. With ``V_s = r * wheel`` and steering angle ``a``:

    .. math::

        \omega = \frac{V_s}{d}\sin a,\quad v_x = V_s \cos a,\quad v_y = 0.

    ``a = 0`` drives straight, ``a = +-pi/2`` rotates in place about the rear axle midpoint.

    Parameters
    ----------
    wheel_radius : float
        Steered wheel radius, m.
    wheelbase : float
        d, rear axle to steered wheel, m.
    """

    wheel_radius: float
    wheelbase: float

    name: ClassVar[str] = "tricycle"
    input_names: ClassVar[tuple[str, ...]] = ("wheel", "steer")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "steer")
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheelbase")

    def twist(self, u) -> np.ndarray:
        """``[V_s sin(a) / d, V_s cos(a), 0]``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        V = self.wheel_radius * U[:, 0]
        a = U[:, 1]
        T = np.stack([V * np.sin(a) / self.wheelbase, V * np.cos(a), np.zeros_like(V)], axis=1)
        return _out(T, single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, 2)`` or ``(N, 3, 2)``; smooth for every steering angle."""
        U, single = self._u(u)
        r, d = self.wheel_radius, self.wheelbase
        V, a = r * U[:, 0], U[:, 1]
        J = np.zeros((U.shape[0], 3, 2))
        J[:, 0, 0] = r * np.sin(a) / d
        J[:, 0, 1] = V * np.cos(a) / d
        J[:, 1, 0] = r * np.cos(a)
        J[:, 1, 1] = -V * np.sin(a)
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius, 0.0])

    def inverse(self, twist) -> np.ndarray:
        """``(wheel, steer)`` with ``steer`` in ``(-pi/2, pi/2]``; 0 for a standstill.

        Raises ``ValueError`` for ``v_y != 0`` (the rear axle cannot slide sideways).
        """
        T, single = _twists(twist, "Tricycle.inverse")
        _nonholonomic_vy(T, "Tricycle")
        speed, steer = _steered_wheel_inverse(T[:, 1], T[:, 0] * self.wheelbase)
        return _out(np.stack([speed / self.wheel_radius, steer], axis=1), single)


@dataclass(frozen=True)
class Bicycle(_Drive):
    r"""Bicycle approximation of a car, Politecnico slides (``003_...``).

    ``V`` is the speed at the rear axle midpoint (the body origin), ``V = r * rear`` where
    ``rear`` is the angle increment of a virtual rear wheel (the mean of the two rear wheels);
    ``a`` is the virtual front wheel's steering angle and ``d`` the wheelbase:

    .. math::

        \omega = V \frac{\tan a}{d},\quad v_x = V,\quad v_y = 0.

    The model is singular at ``a = +-pi/2`` (use :class:`Tricycle` there); such inputs raise
    ``ValueError``.

    Parameters
    ----------
    wheel_radius : float
        Rear wheel radius, m.
    wheelbase : float
        d, rear to front axle, m.
    """

    wheel_radius: float
    wheelbase: float

    name: ClassVar[str] = "bicycle"
    input_names: ClassVar[tuple[str, ...]] = ("rear", "steer")
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel", "steer")
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheelbase")

    def _u(self, u):
        U, single = super()._u(u)
        bad = np.abs(U[:, 1]) >= 0.5 * np.pi - 1e-9
        if bad.any():
            row = int(np.argmax(bad))
            raise ValueError(
                f"Bicycle: steering angle {U[row, 1]!r} in row {row}, column 'steer' is at or "
                "beyond +-pi/2 where tan(a) is singular"
            )
        return U, single

    def twist(self, u) -> np.ndarray:
        """``[V tan(a) / d, V, 0]``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        V = self.wheel_radius * U[:, 0]
        T = np.stack([V * np.tan(U[:, 1]) / self.wheelbase, V, np.zeros_like(V)], axis=1)
        return _out(T, single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, 2)`` or ``(N, 3, 2)``."""
        U, single = self._u(u)
        r, d = self.wheel_radius, self.wheelbase
        V, a = r * U[:, 0], U[:, 1]
        J = np.zeros((U.shape[0], 3, 2))
        J[:, 0, 0] = r * np.tan(a) / d
        J[:, 0, 1] = V / (d * np.cos(a) ** 2)
        J[:, 1, 0] = r
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius, 0.0])

    def inverse(self, twist) -> np.ndarray:
        """``(rear, steer)`` with ``tan(steer) = omega d / v_x``.

        Raises ``ValueError`` for ``v_y != 0`` or for a rotation without forward motion
        (``v_x = 0``, ``omega != 0``), which needs ``steer = pi/2``.
        """
        T, single = _twists(twist, "Bicycle.inverse")
        _nonholonomic_vy(T, "Bicycle")
        w, vx = T[:, 0], T[:, 1]
        scale = 1.0 + np.linalg.norm(T, axis=1)
        _unreachable(
            (vx == 0.0) & (np.abs(w) > _REACH_TOL * scale),
            np.abs(w),
            "Bicycle",
            "turning on the spot needs steer = pi/2",
        )
        s = np.where(vx < 0.0, -1.0, 1.0)
        steer = np.arctan2(s * w * self.wheelbase, s * vx)
        return _out(np.stack([vx / self.wheel_radius, steer], axis=1), single)


@dataclass(frozen=True)
class Ackermann(_Drive):
    r"""Car with Ackermann steering, per-wheel kinematics of the Politecnico slides (``003_...``).

    Body frame at the rear axle midpoint, x forward, y left; ``b = track_width / 2``,
    ``d = wheelbase``. Wheels: front-left ``(d, b)`` and front-right ``(d, -b)`` steered by
    ``steer_left``/``steer_right``, rear-left ``(0, b)`` and rear-right ``(0, -b)`` fixed.
    The two fixed rear wheels force ``v_y = 0`` (their no-side-slip constraints). A wheel at
    ``(x_i, y_i)`` steered by ``delta_i`` rolls by

    .. math::

        r\,\Delta\phi_i = \cos\delta_i\,v_x + (x_i\sin\delta_i - y_i\cos\delta_i)\,\omega

    (the ``h_i`` rows of Modern Robotics 13.5 with ``gamma = 0``). Forward kinematics fuses the
    four rolling constraints by unweighted least squares over ``(omega, v_x)``:
    ``z = (A^T A)^{-1} A^T s`` with ``A`` the ``(4, 2)`` matrix of the rows above and
    ``s = r Delta phi`` (maximum likelihood for equal, independent wheel noise); for consistent
    inputs the residual is zero and this is the slides' exact kinematics
    (``omega (R +- b) = V_B{L,R}``, ``omega d / sin(alpha) = V_F``). The steering angles enter
    only through ``A``; the Jacobian differentiates the least-squares solution analytically.

    Inverse kinematics returns the four wheel increments and both Ackermann steering angles
    ``tan(delta_{L,R}) = d / (R -+ b)`` with ``R = v_x / omega`` (left turn positive); the ICR is
    ``(0, R)``, on the rear axle line.

    Parameters
    ----------
    wheel_radius : float
        m, all four wheels.
    wheelbase : float
        d, rear to front axle, m.
    track_width : float
        2b, left to right wheel, m.
    """

    wheel_radius: float
    wheelbase: float
    track_width: float

    name: ClassVar[str] = "ackermann"
    input_names: ClassVar[tuple[str, ...]] = (
        "front_left",
        "front_right",
        "rear_left",
        "rear_right",
        "steer_left",
        "steer_right",
    )
    input_kinds: ClassVar[tuple[str, ...]] = ("wheel",) * 4 + ("steer",) * 2
    degree_of_mobility: ClassVar[int] = 1
    degree_of_steerability: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(self, "wheel_radius", "wheelbase", "track_width")

    def _design(self, dl: np.ndarray, dr: np.ndarray):
        """Rows ``A (N, 4, 2)`` over ``(omega, v_x)`` and their steering derivatives."""
        d, b = self.wheelbase, 0.5 * self.track_width
        N = dl.shape[0]
        A = np.empty((N, 4, 2))
        A[:, 0] = np.stack([d * np.sin(dl) - b * np.cos(dl), np.cos(dl)], axis=1)
        A[:, 1] = np.stack([d * np.sin(dr) + b * np.cos(dr), np.cos(dr)], axis=1)
        A[:, 2] = (-b, 1.0)
        A[:, 3] = (b, 1.0)
        dA_l = np.stack([d * np.cos(dl) + b * np.sin(dl), -np.sin(dl)], axis=1)
        dA_r = np.stack([d * np.cos(dr) - b * np.sin(dr), -np.sin(dr)], axis=1)
        return A, dA_l, dA_r

    def _solve(self, U: np.ndarray):
        s = self.wheel_radius * U[:, :4]
        A, dA_l, dA_r = self._design(U[:, 4], U[:, 5])
        At = np.swapaxes(A, 1, 2)
        G = At @ A  # (N, 2, 2); always invertible: the rear rows alone have rank 2
        z = np.linalg.solve(G, (At @ s[:, :, None]))[:, :, 0]
        return z, s, A, At, G, dA_l, dA_r

    def twist(self, u) -> np.ndarray:
        """Least-squares twist ``[omega, v_x, 0]``; ``(3,)`` or ``(N, 3)``."""
        U, single = self._u(u)
        z = self._solve(U)[0]
        return _out(np.column_stack([z, np.zeros(len(z))]), single)

    def J_twist_u(self, u) -> np.ndarray:
        """Analytic Jacobian ``(3, 6)`` or ``(N, 3, 6)``.

        With ``G = A^T A`` and residual ``e = s - A z``: ``dz/ds = G^{-1} A^T`` and, for a
        steering angle changing row ``k`` of ``A`` by ``a_k'``,
        ``dz/d delta = G^{-1} (a_k' e_k - a_k (a_k' . z))``.
        """
        U, single = self._u(u)
        z, s, A, At, G, dA_l, dA_r = self._solve(U)
        N = U.shape[0]
        e = s - (A @ z[:, :, None])[:, :, 0]
        rhs = np.empty((N, 2, 6))
        rhs[:, :, :4] = At * self.wheel_radius
        for col, k, da in ((4, 0, dA_l), (5, 1, dA_r)):
            rhs[:, :, col] = da * e[:, k : k + 1] - A[:, k] * np.sum(da * z, axis=1, keepdims=True)
        Jz = np.linalg.solve(G, rhs)
        J = np.concatenate([Jz, np.zeros((N, 1, 6))], axis=1)
        return _out(J, single)

    def travel_scale(self) -> np.ndarray:
        return np.array([self.wheel_radius] * 4 + [0.0, 0.0])

    def inverse(self, twist) -> np.ndarray:
        """Wheel increments of all four wheels and both steering angles for ``twist``.

        Steering angles lie in ``(-pi/2, pi/2]``; a front wheel whose contact point moves
        backwards rolls backwards. Raises ``ValueError`` for ``v_y != 0``.
        """
        T, single = _twists(twist, "Ackermann.inverse")
        _nonholonomic_vy(T, "Ackermann")
        w, vx = T[:, 0], T[:, 1]
        d, b, r = self.wheelbase, 0.5 * self.track_width, self.wheel_radius
        s_fl, d_l = _steered_wheel_inverse(vx - w * b, w * d)
        s_fr, d_r = _steered_wheel_inverse(vx + w * b, w * d)
        out = np.stack([s_fl / r, s_fr / r, (vx - w * b) / r, (vx + w * b) / r, d_l, d_r], axis=1)
        return _out(out, single)


# --------------------------------------------------------------------------- registry
DRIVES: dict[str, type] = {
    cls.name: cls
    for cls in (
        Differential,
        SkidSteer,
        Tricycle,
        Ackermann,
        Bicycle,
        Synchro,
        Omni3,
        Mecanum4,
        Generic,
        Increments,
    )
}


def _load_class(spec: str) -> type:
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise ConfigError(f"drive '{spec}': expected 'package.module:Class'", key="drive")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(
            f"drive '{spec}': cannot import module '{module_name}' ({exc})", key="drive"
        ) from None
    try:
        return getattr(module, attr)
    except AttributeError:
        raise ConfigError(
            f"drive '{spec}': module '{module_name}' has no '{attr}'", key="drive"
        ) from None


def make_drive(name: str, **geometry):
    """Build a drive model from its registry name (or ``"package.module:Class"``) and geometry.

    Parameters
    ----------
    name : str
        A key of :data:`DRIVES` or ``"package.module:Class"`` for a user plug-in.
    **geometry
        The class's constructor arguments (e.g. ``wheel_radius=0.04, track_width=0.235``).

    Returns
    -------
    DriveModel

    Raises
    ------
    ValueError (:class:`odofuse.errors.ConfigError`)
        For an unknown drive name, an unknown or missing geometry key (the message names the
        key), or an invalid value.
    """
    if not isinstance(name, str):
        raise ConfigError(f"drive name must be a string, got {name!r}", key="drive")
    if ":" in name:
        cls = _load_class(name)
    elif name in DRIVES:
        cls = DRIVES[name]
    else:
        raise ConfigError(
            f"unknown drive '{name}'; known: {', '.join(sorted(DRIVES))}", key="drive"
        )
    if dataclasses.is_dataclass(cls):
        fields = [f for f in dataclasses.fields(cls) if f.init]
        known = {f.name for f in fields}
        for key in geometry:
            if key not in known:
                raise ConfigError(
                    f"drive '{name}': unknown geometry key '{key}'; accepted: "
                    f"{', '.join(sorted(known)) or 'none'}",
                    key=key,
                )
        for f in fields:
            no_default = (
                f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
            )
            if no_default and f.name not in geometry:
                raise ConfigError(f"drive '{name}': missing geometry key '{f.name}'", key=f.name)
        return cls(**geometry)
    try:
        return cls(**geometry)
    except TypeError as exc:
        raise ConfigError(f"drive '{name}': bad geometry ({exc})", key="drive") from None


# --------------------------------------------------------------------------- inverse kinematics
def turn_drive_turn(start_pose, goal_pose) -> np.ndarray:
    """Turn-drive-turn inverse kinematics (Politecnico slides ``003_...``).

    1. rotate on the spot to face the goal position, 2. drive straight to it,
    3. rotate to the goal heading. Turns are wrapped to ``[-pi, pi)`` (the shorter way).

    Parameters
    ----------
    start_pose, goal_pose : array_like, shape (3,)
        ``[x, y, theta]`` in the world frame (m, m, rad).

    Returns
    -------
    ndarray, shape (3, 3)
        Three body twists (one per row, Delta t = 1): ``[omega1, 0, 0]``,
        ``[0, dist, 0]``, ``[omega2, 0, 0]``. When the positions coincide the first turn is 0
        and the whole rotation is in the last segment.
    """
    p0 = np.asarray(start_pose, dtype=float)
    p1 = np.asarray(goal_pose, dtype=float)
    for what, p in (("start_pose", p0), ("goal_pose", p1)):
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(
                f"turn_drive_turn: {what} must be a finite (3,) [x, y, theta], got {p!r}"
            )
    dx, dy = p1[:2] - p0[:2]
    dist = float(np.hypot(dx, dy))
    if dist == 0.0:
        heading = p0[2]
    else:
        heading = math.atan2(dy, dx)
    turn1 = float(wrap(heading - p0[2]))
    turn2 = float(wrap(p1[2] - heading))
    return np.array([[turn1, 0.0, 0.0], [0.0, dist, 0.0], [turn2, 0.0, 0.0]])
