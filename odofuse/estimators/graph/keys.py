"""GTSAM keys of the graph's variables and the sensor-kind names the graph dispatches on.

Poses are ``x<i>`` (keyframe ``i``), landmarks ``l<id>``, the private beacon copies of frozen
range factors ``b<n>``, the sensor calibration states ``c<n>`` and the later segments of a
walking gyro bias ``w<n, j>`` (:func:`W`); the odometry calibration vector is ``o0``
(:attr:`odofuse.estimators.graph.problem.GraphProblem.odometry_key`).
"""

from __future__ import annotations


def X(i: int) -> int:
    """GTSAM key of the pose of keyframe ``i``."""
    import gtsam

    return gtsam.symbol("x", int(i))


def L(i: int) -> int:
    """GTSAM key of landmark ``i`` (its map id)."""
    import gtsam

    return gtsam.symbol("l", int(i))


def B(i: int) -> int:
    """GTSAM key of the ``i``-th private beacon copy of a frozen range factor."""
    import gtsam

    return gtsam.symbol("b", int(i))


def C(i: int) -> int:
    """GTSAM key of the ``i``-th sensor calibration state."""
    import gtsam

    return gtsam.symbol("c", int(i))


def W(n: int, j: int) -> int:
    """GTSAM key of segment ``j >= 1`` of the walking bias whose first segment is ``C(n)``."""
    import gtsam

    return gtsam.symbol("w", (int(n) << 32) | int(j))


def is_vector(key: int) -> bool:
    """Whether ``key`` is a calibration vector (``c``, ``w`` or ``o``: ``gtsam.Values.atVector``);
    the other keys are poses (``x``) and points (``l``, ``b``)."""
    import gtsam

    return gtsam.Symbol(key).chr() in (ord("c"), ord("o"), ord("w"))


def model_kind(model) -> str:
    """The measurement model's class name (``"BeaconRange"``, ``"GyroYawRate"``, ...)."""
    return type(model).__name__
