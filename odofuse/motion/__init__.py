"""Motion models: integrators, the odometry error model and dead reckoning.

One :class:`MotionModel` (drive + error model + integrator) serves every back end: the EKF/UKF
prediction, the particle filter's sampling and the factor graph's odometry factors all call it.

Integrators (Politecnico slides ``003_73fced8ec7c15fe5.txt``, Modern Robotics 13.35-13.36 in
``000_96a7e9c96987202e.txt``), for a step's body twist ``[omega, v_x, v_y]`` (Delta t = 1):

* ``euler``: the body moves by ``[v_x, v_y]`` along the heading at the step start;
* ``rk2``: the same along the mid-step heading ``theta + omega/2`` (Siegwart's model in
  ``004_f4547100a083f338.txt`` is this one with ``v_y = 0``);
* ``exact``: the twist exponential (arc of a circle about the ICR);
* ``euler_end``: the body moves by ``[v_x, v_y]`` along the heading at the step *end*
  (``theta + omega``): heading first, then position, as ros2_controllers' mecanum drive
  controller integrates (``mecanum_drive_controller/src/odometry.cpp``, ``Odometry::update``).

Error model (Siegwart & Nourbakhsh ch. 5): each wheel's travel ``ds_i`` has variance
``k_i |ds_i|`` (m^2 per m), uncorrelated between wheels; steering inputs have a constant
variance; every input may add a per-step and a per-second floor. Increment and twist inputs
add a heading variance per metre travelled (:func:`implied_k_theta_ds`), so driving straight
never claims a perfect heading. ``Sigma_p' = F_p Sigma_p F_p^T + F_u Sigma_u F_u^T``.
Velocity inputs (the ``twist`` and ``increments`` drives) may add Thrun's quadratic
velocity-model terms (``OdometryErrorModel.quadratic``).
Redundant wheels (``wheels_per_side``) are checked against their side mates by
:func:`side_outliers`.

Modules: ``integrators`` (one step's twist into a relative pose), ``noise`` (the error
models), ``model`` (:class:`MotionModel`, :func:`dead_reckon`); every public name is
importable from ``odofuse.motion``.
"""

from odofuse.declarations import INTEGRATORS
from odofuse.motion.integrators import body_increment, integrate
from odofuse.motion.model import (
    GEOMETRY_EXCLUDE,
    MotionModel,
    dead_reckon,
    linear_terms,
    motion_model_from_config,
    side_outliers,
)
from odofuse.motion.noise import (
    OdometryErrorModel,
    ThrunOdometryModel,
    error_model_from_config,
    implied_k_theta_ds,
)

__all__ = [
    "GEOMETRY_EXCLUDE",
    "INTEGRATORS",
    "MotionModel",
    "OdometryErrorModel",
    "ThrunOdometryModel",
    "body_increment",
    "dead_reckon",
    "error_model_from_config",
    "implied_k_theta_ds",
    "integrate",
    "linear_terms",
    "motion_model_from_config",
    "side_outliers",
]
