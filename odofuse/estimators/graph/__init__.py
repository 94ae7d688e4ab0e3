"""GTSAM factor-graph back end: batch smoother, iSAM2 and a fixed-lag smoother.

The graph is built from the run's single :class:`odofuse.motion.MotionModel` and its
:mod:`odofuse.measurements` models, so it cannot drift apart from the filters:

* **Keyframes** at every sensor time (ranges, GPS, ...), every ``keyframe_dt`` seconds and,
  optionally, every ``keyframe_ds`` metres / ``keyframe_dtheta`` radians of odometry (or at
  every odometry row with ``keyframe_every_step``). An odometry step straddling a keyframe is
  split: its wheel / increment inputs are scaled by the time fraction (steering angles are
  held), which is exact for the constant-twist step of the ``exact`` integrator.
* **Odometry factors**: the steps between two keyframes are pre-integrated with
  ``MotionModel.relative`` (Siegwart error model, ``004_f4547100a083f338.txt`` ch. 5; head-to-tail
  composition, ``002_88fc37db58155723.txt``) into a ``BetweenFactorPose2`` whose covariance is
  already in GTSAM's body (tangent) convention.
* **Gyro factors**: the gyro samples between two keyframes are pre-integrated into one
  heading increment (:func:`~odofuse.estimators.graph.keyframes.preintegrate_gyro`) with the
  bias as a variable; gyro times are not keyframes.
* **Sensor factors** come from each model's ``factor`` (built-in ``PoseTranslationPrior2D``,
  ``RangeFactor2D``, ``BearingRangeFactor2D``, ... where GTSAM has one), wrapped in a
  Huber / Cauchy / Tukey loss per stream. Calibration states of the models (range scale and
  offset, gyro bias, compass offset) become graph variables with the models' priors.
* **Landmarks**: known (a tightly fixed ``Point2`` variable per map entry, or the model's unary
  factor when calibration variables are involved) or unknown (``slam: true``: a variable per
  id, initialised by a robust grid search of the ranges against the dead-reckoned path).

Solvers: batch Levenberg-Marquardt (:func:`run_smoother`), iSAM2 one update per keyframe
(:func:`run_isam2`) and GTSAM's ``IncrementalFixedLagSmoother`` (:func:`run_fixed_lag`).
Marginal covariances are converted to the world frame with :func:`odofuse.se2.cov_body_to_world`.
The options are :class:`~odofuse.declarations.GraphOptions` (declared with the other blocks in
:mod:`odofuse.declarations.graph`, validated with the config, documented in ``docs/graph.md``);
the estimators read them as ``config.estimator_options(estimator)``.

The package is split by role, each module importing only those above it:

``keys``
    GTSAM keys of the variables and the sensor kinds the graph dispatches on.
``keyframes``
    :func:`keyframe_times`, :func:`preintegrate` (odometry between keyframes),
    ``preintegrate_gyro`` (gyro samples between keyframes).
``calibration``
    :class:`OdometryCalibration` (systematic odometry parameters per drive).
``slam``
    :func:`slam_initial_landmarks` (unknown landmarks' initial positions).
``problem``
    :class:`GraphProblem`, :func:`build_problem` (no GTSAM objects).
``custom_factors``
    ``gtsam.CustomFactor`` factors for what GTSAM has no built-in factor for.
``factors``
    ``Factors``: a problem as GTSAM factors and values, keyframe by keyframe.
``health``
    The graph's self-checks (residuals, outliers, calibration, jumps, solver): findings.
``solvers``
    :func:`build_graph`, :func:`run_smoother` (batch LM, in stages for robust odometry with
    odometry calibration) and the shared results.
``isam2``
    :func:`run_isam2` (with the calibration freeze), :func:`run_fixed_lag`.
"""

from odofuse.declarations import GraphOptions
from odofuse.estimators.graph.calibration import OdometryCalibration, odometry_calibration_for
from odofuse.estimators.graph.isam2 import run_fixed_lag, run_isam2
from odofuse.estimators.graph.keyframes import keyframe_times, preintegrate
from odofuse.estimators.graph.problem import GraphProblem, build_problem
from odofuse.estimators.graph.slam import slam_initial_landmarks
from odofuse.estimators.graph.solvers import build_graph, run_smoother

__all__ = [
    "GraphOptions",
    "GraphProblem",
    "keyframe_times",
    "preintegrate",
    "OdometryCalibration",
    "odometry_calibration_for",
    "build_problem",
    "build_graph",
    "slam_initial_landmarks",
    "run_smoother",
    "run_isam2",
    "run_fixed_lag",
]
