"""Drives whose inputs are body motion rather than wheels: odometry increments."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from odofuse.drives.base import _LinearDrive


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
