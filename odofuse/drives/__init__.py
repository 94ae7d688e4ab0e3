"""Drive models: wheel readings -> body twist, its Jacobian, inverse kinematics and ICR.

The contract is described in :mod:`odofuse.drives.base`; one module per drive family:

=================================  ==========================================================
:mod:`~odofuse.drives.differential`  :class:`Differential` (Modern Robotics eq. 13.34),
                                     :class:`SkidSteer` (Politecnico slides ``003_...``)
:mod:`~odofuse.drives.steered`       :class:`Tricycle`, :class:`Bicycle`, :class:`Ackermann`,
                                     :class:`Synchro` (Politecnico slides ``003_...``)
:mod:`~odofuse.drives.omni`          :class:`Omni3`, :class:`Mecanum4` (MR eqs. 13.32-13.33),
                                     :class:`Generic` (MR 13.5 / 13.8, F = pinv(H(0)))
:mod:`~odofuse.drives.twist`         :class:`Increments` (``odometry.csv``, Plaza ``DR``)
:mod:`~odofuse.drives.registry`      :data:`DRIVES`, :func:`make_drive`
=================================  ==========================================================
"""

from odofuse.drives.base import icr, turn_drive_turn
from odofuse.drives.differential import Differential, SkidSteer
from odofuse.drives.omni import Generic, Mecanum4, Omni3
from odofuse.drives.registry import DRIVES, make_drive
from odofuse.drives.steered import Ackermann, Bicycle, Synchro, Tricycle
from odofuse.drives.twist import Increments

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
