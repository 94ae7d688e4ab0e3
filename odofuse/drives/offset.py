r"""A drive whose base frame is offset from its kinematic centre (ros2_controllers' mecanum).

ros2_controllers' mecanum drive controller computes the twist at the kinematic centre ``C``
and reports it at ``base_link`` ``B``, given by ``base_frame_offset = (x, y, theta)``, the pose
of ``B`` in ``C`` (``mecanum_drive_controller/src/odometry.cpp``, ``Odometry::update``). Over
a step ``C`` moves by ``exp(xi_C)``; ``B = C T`` moves by ``T^{-1} exp(xi_C) T =
exp(Ad_{T^{-1}} xi_C)``, so with ``q = R(theta)^T p``

.. math::

    \omega_B = \omega_C,\qquad
    v_B = R(\theta)^T v_C + \omega_C \begin{bmatrix} -q_y \\ q_x \end{bmatrix},

the same linear map as the controller's, exact for the twist exponential. ``twist``,
``J_twist_u`` and ``inverse`` go through this ``3 x 3`` matrix ``M``; the inputs, their kinds,
travel and noise are the wrapped drive's. Built by ``make_drive`` when the geometry holds
``base_frame_offset: [x, y, theta]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from odofuse.drives.base import _Drive, _out, _twists
from odofuse.errors import ConfigError


@dataclass(frozen=True)
class Offset(_Drive):
    """``drive`` reported at a base frame with pose ``offset`` in its kinematic-centre frame.

    Parameters
    ----------
    drive : DriveModel
        The drive at its kinematic centre.
    offset : sequence of 3 float
        ``(x, y, theta)`` of the base frame in the centre frame (m, m, rad).
    """

    drive: Any
    offset: Any

    def __post_init__(self) -> None:
        try:
            o = np.asarray(self.offset, dtype=float)
        except (TypeError, ValueError):
            o = np.full(1, np.nan)
        if o.shape != (3,) or not np.isfinite(o).all():
            raise ConfigError(
                f"base_frame_offset must be [x, y, theta] (m, m, rad), got {self.offset!r}",
                key="base_frame_offset",
            )
        object.__setattr__(self, "offset", tuple(o.tolist()))

    def __getattr__(self, attr):
        # Geometry, names and kinds of the wrapped drive (only reached for missing attributes).
        if attr in ("drive", "offset") or attr.startswith("__"):
            raise AttributeError(attr)
        return getattr(self.drive, attr)

    @property
    def name(self) -> str:  # type: ignore[override]
        return self.drive.name

    @property
    def input_names(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(self.drive.input_names)

    @property
    def input_kinds(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(self.drive.input_kinds)

    def matrix_to_base(self) -> np.ndarray:
        """``M`` with ``twist_B = M twist_C``, ``(3, 3)`` over ``[omega, v_x, v_y]``."""
        x, y, th = self.offset
        c, s = np.cos(th), np.sin(th)
        qx, qy = c * x + s * y, -s * x + c * y
        return np.array([[1.0, 0.0, 0.0], [-qy, c, s], [qx, -s, c]])

    def twist(self, u) -> np.ndarray:
        """The wrapped drive's twist moved to the base frame; ``(3,)`` or ``(N, 3)``."""
        return np.asarray(self.drive.twist(u)) @ self.matrix_to_base().T

    def J_twist_u(self, u) -> np.ndarray:
        """``M J_inner``; ``(3, n)`` or ``(N, 3, n)``."""
        return self.matrix_to_base() @ np.asarray(self.drive.J_twist_u(u))

    def travel_scale(self) -> np.ndarray:
        return np.asarray(self.drive.travel_scale(), dtype=float)

    def travel(self, u) -> np.ndarray:
        return self.drive.travel(u)

    def inverse(self, twist, **options) -> np.ndarray:
        """Inputs producing the base-frame ``twist`` (the wrapped drive's ``inverse``)."""
        T, single = _twists(twist, f"{type(self.drive).__name__}.inverse")
        inner = T @ np.linalg.inv(self.matrix_to_base()).T
        return self.drive.inverse(_out(inner, single), **options)
