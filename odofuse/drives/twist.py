"""Drives whose inputs are body motion rather than wheels: odometry increments and twists.

:class:`Increments` reads ``odometry.csv`` (``ds, dtheta`` per row). :class:`Twist` reads
``cmd_vel.csv`` (``t, v, w`` or ``t, vx, vy, w``): commanded or measured body velocities for
robots without encoders and for the velocity motion model of Thrun, Burgard & Fox (Probabilistic
Robotics, Table 5.3) and the Siegwart slides. A row's velocity is held until the next row
(zero-order hold, as a controller applies a command), so step ``k`` moves by
``u_k = v_k (t_{k+1} - t_k)``: the drive's input is that increment (m, m, rad), and
``twist = [w dt, v dt, 0]`` (or ``[w dt, vx dt, vy dt]``).

Noise (``motion.alphas: [a1, a2, a3, a4]``, Thrun Table 5.3, on **variances**, for both drives:
an increment ``(ds, dtheta)`` is a twist ``(v dt, w dt)``):
``var(v dt) = a1 (v dt)^2 + a2 (w dt)^2`` and ``var(w dt) = a3 (v dt)^2 + a4 (w dt)^2``
(for the holonomic form ``(v dt)^2 = (vx dt)^2 + (vy dt)^2`` and both ``vx`` and ``vy`` get
the first law). Thrun's extra final rotation (``a5, a6``) is not modelled.

Both drives name their heading input (``heading_input``) and their translation inputs
(``translation_inputs``) for the distance-driven heading variance ``motion.k_theta_ds``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from odofuse.drives.base import _LinearDrive
from odofuse.errors import ConfigError


def thrun_quadratic(alphas, holonomic: bool, who: str) -> np.ndarray:
    """``Q`` with ``var(u_i) = sum_j Q_ij u_j^2`` from Thrun's ``[a1, a2, a3, a4]`` (variances).

    Inputs ``(v dt, w dt)``, or ``(vx dt, vy dt, w dt)`` when ``holonomic``.
    """
    a = np.asarray(alphas, dtype=float)
    if a.shape != (4,) or not (np.isfinite(a).all() and (a >= 0).all()):
        raise ConfigError(
            f"{who}: alphas must be four non-negative numbers, got {alphas!r}", key="alphas"
        )
    a1, a2, a3, a4 = a
    if holonomic:
        return np.array([[a1, a1, a2], [a1, a1, a2], [a3, a3, a4]])
    return np.array([[a1, a2], [a3, a4]])


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
    heading_input: ClassVar[int] = 1
    translation_inputs: ClassVar[tuple[int, ...]] = (0,)

    def matrix(self) -> np.ndarray:
        return np.array([[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]])

    def travel_scale(self) -> np.ndarray:
        return np.ones(2)

    def quadratic_noise(self, alphas) -> np.ndarray:
        """Thrun's velocity model on ``(ds, dtheta)`` (:func:`thrun_quadratic`)."""
        return thrun_quadratic(alphas, False, "Increments")


@dataclass(frozen=True)
class Twist(_LinearDrive):
    """Body twists from ``cmd_vel.csv``, integrated per row interval (module docstring).

    Parameters
    ----------
    holonomic : bool, optional
        ``False`` (default): columns ``v, w`` (a unicycle); ``True``: ``vx, vy, w``.
    """

    holonomic: bool = False

    name: ClassVar[str] = "twist"

    def __post_init__(self) -> None:
        if not isinstance(self.holonomic, bool):
            raise ConfigError(
                f"Twist: holonomic must be true or false, got {self.holonomic!r}", key="holonomic"
            )

    @property
    def input_names(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("vx", "vy", "w") if self.holonomic else ("v", "w")

    @property
    def input_kinds(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("velocity",) * len(self.input_names)

    @property
    def degree_of_mobility(self) -> int:  # type: ignore[override]
        return 3 if self.holonomic else 2

    def matrix(self) -> np.ndarray:
        if self.holonomic:
            return np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        return np.array([[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]])

    def travel_scale(self) -> np.ndarray:
        return np.ones(len(self.input_names))

    @property
    def heading_input(self) -> int:
        return len(self.input_names) - 1

    @property
    def translation_inputs(self) -> tuple[int, ...]:
        return (0, 1) if self.holonomic else (0,)

    def quadratic_noise(self, alphas) -> np.ndarray:
        """``Q`` with ``var(u_i) = sum_j Q_ij u_j^2`` from Thrun's ``[a1, a2, a3, a4]``."""
        return thrun_quadratic(alphas, self.holonomic, "Twist")
