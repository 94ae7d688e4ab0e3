"""Measurement models: one interface for every exteroceptive/proprioceptive sensor.

Each model maps the filter state ``x`` (``x[:3]`` the world pose ``[x, y, theta]``,
``x[3:]`` augmented calibration/clone states) and one stream row to a predicted measurement
``h(x, row)``, its analytic Jacobian ``H(x, row)`` of shape ``(dim, len(x))``, the noise
``R(row)`` and an angle-aware ``residual(z, z_hat)``. The same model also yields a GTSAM
factor (``factor``) so the Kalman filters and the factor graph share one definition.

Augmented states
----------------
A model lists the names of the augmented states it reads in ``calib_states`` (for example
``("range_scale", "range_offset")``). The filter appends all names used by the run's models
after ``[x, y, theta]`` in first-seen order, then hands each model the name -> index map with
:meth:`MeasurementModel.bind`. An unbound model (or a state missing from the map) uses the
state's nominal value (scale 1, offsets and biases 0), so ``h`` also works on a bare pose.
``calib_prior()`` gives each state's initial value and standard deviation and
``calib_walk()`` its random-walk density (units per sqrt(s)).

Models
------
``GpsPosition`` (local metres or WGS-84 lat/lon converted to ENU about a datum, optional
antenna lever arm), ``GyroYawRate`` (yaw rate against the heading change since the previous
gyro sample, via a cloned heading state), ``CompassHeading``, ``BeaconRange`` (range to a
known beacon, optional scale/offset calibration), ``LandmarkBearing`` and
``LandmarkRangeBearing`` (robot-frame range and bearing to a mapped landmark). The geometry
is the head-to-tail composition of ``002_88fc37db58155723.txt`` and the rotation
``R(theta)`` of Siegwart & Nourbakhsh ch. 3 (``004_f4547100a083f338.txt``).

User models are named in the sensor block as ``class: "package.module:Class"``; the class is
called as ``Class(name=stream, **keys)`` (plus ``landmarks=`` the map when it takes that
keyword; ``class``, ``gate`` and ``robust`` are not passed) and must provide the attributes
and methods of :class:`MeasurementModel`. A class that declares its keys as a frozen dataclass
``Options`` (fields made with :func:`odofuse.options.option`) gets them validated and
default-filled; otherwise its keys are passed unchecked.

Modules
-------
``base`` (the interface and the gate), ``absolute`` (GPS, compass), ``gyro``, ``landmarks``
(beacon range, bearing, range-bearing) and ``registry`` (:data:`MODELS`,
:func:`measurement_models`); every public name is importable from ``odofuse.measurements``.
"""

from odofuse.declarations import STREAM_DEFAULTS
from odofuse.measurements.absolute import CompassHeading, GpsPosition
from odofuse.measurements.base import MeasurementModel, gate_threshold
from odofuse.measurements.gyro import GyroYawRate
from odofuse.measurements.landmarks import BeaconRange, LandmarkBearing, LandmarkRangeBearing
from odofuse.measurements.registry import MODELS, measurement_models
from odofuse.se2 import wrap

__all__ = [
    "MeasurementModel",
    "GpsPosition",
    "GyroYawRate",
    "CompassHeading",
    "BeaconRange",
    "LandmarkBearing",
    "LandmarkRangeBearing",
    "MODELS",
    "STREAM_DEFAULTS",
    "measurement_models",
    "gate_threshold",
    "wrap",
]
