"""Drive models: wheel readings -> body twist, its Jacobian, inverse kinematics and ICR.

The contract is described in :mod:`odofuse.drives.base`; one module per drive family:

=================================  ==========================================================
:mod:`~odofuse.drives.differential`  :class:`Differential` (Modern Robotics eq. 13.34),
                                     :class:`SkidSteer` (Politecnico slides ``003_...``)
:mod:`~odofuse.drives.steered`       :class:`Tricycle`, :class:`Bicycle`, :class:`Ackermann`,
                                     :class:`Synchro` (Politecnico slides ``003_...``)
:mod:`~odofuse.drives.omni`          :class:`Omni3`, :class:`Mecanum4` (MR eqs. 13.32-13.33),
                                     :class:`Generic` (MR 13.5 / 13.8, F = pinv(H(0)))
:mod:`~odofuse.drives.swerve`        :class:`Swerve` (WPILib ``SwerveDriveKinematics``)
:mod:`~odofuse.drives.car`           :class:`Car`, :class:`CarAckermann` (rear encoders,
                                     ros2_controllers' steering odometry)
:mod:`~odofuse.drives.twist`         :class:`Increments` (``odometry.csv``, Plaza ``DR``),
                                     :class:`Twist` (``cmd_vel.csv``, Thrun's velocity model)
:mod:`~odofuse.drives.offset`        :class:`Offset` (``base_frame_offset``)
:mod:`~odofuse.drives.registry`      :data:`DRIVES`, :func:`make_drive`
=================================  ==========================================================
"""

from odofuse.drives.base import icr, turn_drive_turn
from odofuse.drives.car import Car, CarAckermann
from odofuse.drives.differential import Differential, SkidSteer
from odofuse.drives.offset import Offset
from odofuse.drives.omni import Generic, Mecanum4, Omni3
from odofuse.drives.registry import DRIVES, make_drive
from odofuse.drives.steered import Ackermann, Bicycle, Synchro, Tricycle
from odofuse.drives.swerve import Swerve, desaturate, optimize_angles
from odofuse.drives.twist import Increments, Twist

__all__ = [
    "DRIVES",
    "Ackermann",
    "Bicycle",
    "Car",
    "CarAckermann",
    "Differential",
    "Generic",
    "Increments",
    "Mecanum4",
    "Offset",
    "Omni3",
    "SkidSteer",
    "Swerve",
    "Synchro",
    "Tricycle",
    "Twist",
    "desaturate",
    "icr",
    "make_drive",
    "optimize_angles",
    "turn_drive_turn",
]
