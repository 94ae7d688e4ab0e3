"""ROS messages in and out of the live component.

In: one message at a time -> the Localizer's readings, through the bag reader's own
per-message conversions (:mod:`odofuse.io.ros_msgs`: the same columns, covariance conventions
and IMU mount correction as ``odofuse run`` on a bag). A message that cannot be used raises
:class:`BadMessage` with its reason (``wrong_frame``, ``nan``, ``covariance``,
``time_backwards``, ``no_fix``, ``undecodable``): the component counts and reports it and goes
on.

Out: ``nav_msgs/Odometry``, ``tf2_msgs/TFMessage`` and ``diagnostic_msgs/DiagnosticArray`` as
rosbags message objects, serialised to CDR by the component.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from odofuse.errors import InputError
from odofuse.io import ros_msgs
from odofuse.outputs_ros import ros_pose_covariance

#: Relative tolerance of the PSD check of a message covariance (eigenvalues >= -tol * largest).
PSD_TOL = 1e-9


class BadMessage(Exception):
    """A message the component skips: ``reason`` is the counter it goes to."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason


@dataclass(frozen=True)
class Reading:
    """One Localizer call: ``kind`` ``"odometry"`` (``u``) or ``"measurement"`` (``row``)."""

    kind: str
    t: float
    stream: str = ""
    row: dict | None = None
    u: np.ndarray | None = None


def _finite(*values, what: str) -> None:
    arr = np.asarray([v for v in values], dtype=float).ravel()
    if not np.all(np.isfinite(arr)):
        raise BadMessage("nan", f"{what}: a NaN or infinite value")


def _psd(cov, n: int, what: str) -> None:
    """A known covariance (not all zero, not -1) must be symmetric positive semidefinite."""
    c = np.asarray(cov, dtype=float)
    if c.size == 0 or c[0] == -1.0 or not np.any(c):
        return
    _finite(c, what=what)
    m = c.reshape(n, n)
    d = np.diagonal(m)
    if np.count_nonzero(m) == np.count_nonzero(d):  # diagonal (the usual case): no eig
        if np.any(d < 0.0):
            raise BadMessage("covariance", f"{what}: not symmetric positive semidefinite")
        return
    w = np.linalg.eigvalsh(0.5 * (m + m.T))
    scale = max(float(np.max(np.abs(w))), 1e-300)
    if not np.allclose(m, m.T, rtol=0.0, atol=PSD_TOL * scale) or w[0] < -PSD_TOL * scale:
        raise BadMessage("covariance", f"{what}: not symmetric positive semidefinite")


@dataclass
class TopicDecoder:
    """The readings of one input topic.

    Parameters
    ----------
    topic, kind : str
        The topic and its input kind (``wheels``, ``odometry``, ``gyro``, ``gps``, ``twist``).
    streams : dict
        Stream names this topic feeds: ``{"main": "gyro_2", "compass": "compass_2"}``
        (only those the Localizer uses).
    drive_inputs : tuple of str
        The drive's input names (odometry topics).
    drive_kinds : tuple of str
        Their kinds (``wheel``, ``steer``, ...; :mod:`odofuse.drives`).
    joints : dict or None
        ``{drive input: joint name}`` of a JointState topic.
    yaw_offset : float
        The IMU mount's yaw in the base frame (rad), removed from compass headings.
    frame : str or None
        The frame every message must carry; None: the first message's.
    drop_sigma : frozenset
        Streams whose sensor block sets ``sigma`` (the message covariance is not used).
    """

    topic: str
    kind: str
    streams: dict
    drive_inputs: tuple = ()
    drive_kinds: tuple = ()
    joints: dict | None = None
    yaw_offset: float = 0.0
    frame: str | None = None
    drop_sigma: frozenset = frozenset()
    _prev: tuple | None = field(default=None, repr=False)

    def decode(self, msg) -> list[Reading]:
        t = ros_msgs.stamp(msg, 0)
        _finite(t, what=f"{self.topic} stamp")
        if self.kind in ("gyro", "gps"):
            frame = ros_msgs.frame_of(msg)
            if self.frame is None:
                self.frame = frame
            elif frame != self.frame:
                raise BadMessage(
                    "wrong_frame", f"{self.topic}: frame '{frame}', expected '{self.frame}'"
                )
        return getattr(self, f"_{self.kind}")(t, msg)

    # -- odometry sources -------------------------------------------------------------
    def _step(self, t: float, values: np.ndarray) -> list[Reading]:
        """A step from the previous message's values to these (wheels: differences)."""
        prev, self._prev = self._prev, (t, values)
        if prev is None:
            return [Reading("start", t)]
        if not t > prev[0]:
            self._prev = prev
            raise BadMessage("time_backwards", f"{self.topic}: stamp {t:.6f} <= {prev[0]:.6f}")
        steer = np.array([k == "steer" for k in self.drive_kinds], dtype=bool)
        u = np.where(steer, values, values - prev[1]) if steer.size else values - prev[1]
        return [Reading("odometry", t, u=u)]

    def _wheels(self, t: float, msg) -> list[Reading]:
        if len(msg.position) == 0:
            raise BadMessage("undecodable", f"{self.topic}: JointState without positions")
        try:
            one = ros_msgs.columns([msg], ros_msgs.JOINT_STATE)
            cols, vals = ros_msgs.joint_columns(
                np.array([t]), one, self.joints, self.topic, self.topic, {}, "wheels"
            )
        except InputError as exc:
            raise BadMessage("undecodable", str(exc)) from None
        row = dict(zip(cols, vals[0], strict=True))
        try:
            values = np.array([row[n] for n in self.drive_inputs], dtype=float)
        except KeyError as exc:
            raise BadMessage("undecodable", f"{self.topic}: no joint for input {exc}") from None
        _finite(values, what=f"{self.topic} positions")
        return self._step(t, values)

    def _odometry(self, t: float, msg) -> list[Reading]:
        p = msg.pose.pose
        pose = np.array([p.position.x, p.position.y, ros_msgs.yaw(p.orientation)])
        _finite(pose, what=f"{self.topic} pose")
        _psd(msg.pose.covariance, 6, f"{self.topic} pose covariance")
        _psd(msg.twist.covariance, 6, f"{self.topic} twist covariance")
        prev, self._prev = self._prev, (t, pose)
        if prev is None:
            return [Reading("start", t)]
        if not t > prev[0]:
            self._prev = prev
            raise BadMessage("time_backwards", f"{self.topic}: stamp {t:.6f} <= {prev[0]:.6f}")
        _, inc = ros_msgs.odometry_increments([prev[0], t], np.vstack([prev[1], pose]))
        return [Reading("odometry", t, u=inc[0])]

    def _twist(self, t: float, msg) -> list[Reading]:
        tw = msg.twist
        v = {"v": tw.linear.x, "vx": tw.linear.x, "vy": tw.linear.y, "w": tw.angular.z}
        values = np.array([v[n] for n in self.drive_inputs], dtype=float)
        _finite(values, what=f"{self.topic} twist")
        prev, self._prev = self._prev, (t, values)
        if prev is None:
            return [Reading("start", t)]
        if not t > prev[0]:
            self._prev = prev
            raise BadMessage("time_backwards", f"{self.topic}: stamp {t:.6f} <= {prev[0]:.6f}")
        # the previous command held until now (as odometry_inputs reads cmd_vel.csv)
        return [Reading("odometry", t, u=prev[1] * (t - prev[0]))]

    # -- measurements -----------------------------------------------------------------
    def _row(self, stream: str, t: float, cols, vals) -> Reading:
        row = {"t": float(t)}
        row.update(zip(cols, map(float, vals), strict=True))
        if stream in self.drop_sigma:
            row.pop("sigma", None)
        return Reading("measurement", t, stream, row)

    def _gyro(self, t: float, msg) -> list[Reading]:
        _finite(msg.angular_velocity.z, what=f"{self.topic} angular velocity")
        _psd(msg.angular_velocity_covariance, 3, f"{self.topic} angular velocity covariance")
        _psd(msg.orientation_covariance, 3, f"{self.topic} orientation covariance")
        (gcols, gvals), compass = ros_msgs.imu_columns(
            ros_msgs.columns([msg], ros_msgs.IMU), self.yaw_offset
        )
        out = []
        if "main" in self.streams:
            out.append(self._row(self.streams["main"], t, gcols, gvals[0]))
        if compass is not None and "compass" in self.streams:
            ccols, cvals, _ = compass
            _finite(cvals, what=f"{self.topic} orientation")
            out.append(self._row(self.streams["compass"], t, ccols, cvals[0]))
        return out

    def _gps(self, t: float, msg) -> list[Reading]:
        _psd(msg.position_covariance, 3, f"{self.topic} position covariance")
        cols, vals, keep = ros_msgs.navsat_columns(ros_msgs.columns([msg], ros_msgs.NAVSAT))
        if not keep[0]:
            if msg.status.status < 0:
                raise BadMessage("no_fix", f"{self.topic}: no fix (status {msg.status.status})")
            raise BadMessage("nan", f"{self.topic}: latitude/longitude not finite")
        return [self._row(self.streams["main"], t, cols, vals[0])]


# --------------------------------------------------------------------------- outputs
def _stamp(T, t: float):
    ns = int(round(float(t) * 1e9))
    return T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def _header(T, t: float, frame: str):
    return T["std_msgs/msg/Header"](stamp=_stamp(T, t), frame_id=frame)


def _quat(T, yaw: float):
    return T["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw)
    )


def _v3(T, x=0.0, y=0.0, z=0.0):
    return T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


def odometry_msg(T, t, pose, P, twist, twist_cov, map_frame: str, base_frame: str):
    """``nav_msgs/Odometry``: pose (map frame) + covariance, body twist + covariance.

    ``twist`` is ``[vx, vy, omega]`` in the base frame (m/s, rad/s), its covariance ``(3, 3)``
    at ROS rows/columns 0, 1, 5 as the pose covariance (:func:`ros_pose_covariance`).
    """
    pose = np.asarray(pose, dtype=float)
    return T["nav_msgs/msg/Odometry"](
        header=_header(T, t, map_frame),
        child_frame_id=base_frame,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                orientation=_quat(T, float(pose[2])),
            ),
            covariance=ros_pose_covariance(P),
        ),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](
                linear=_v3(T, twist[0], twist[1]), angular=_v3(T, 0.0, 0.0, twist[2])
            ),
            covariance=ros_pose_covariance(twist_cov),
        ),
    )


def transform(T, t, parent: str, child: str, p):
    """``geometry_msgs/TransformStamped`` of a planar pose ``p`` of ``child`` in ``parent``."""
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(T, t, parent),
        child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=_v3(T, p[0], p[1], p[2] if len(p) > 3 else 0.0),
            rotation=_quat(T, float(p[-1])),
        ),
    )


def tf_msg(T, transforms):
    return T["tf2_msgs/msg/TFMessage"](transforms=list(transforms))


#: diagnostic_msgs/DiagnosticStatus levels.
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR = 0, 1, 2


def diagnostics_msg(T, t, name: str, hardware_id: str, level: int, message: str, values):
    """``diagnostic_msgs/DiagnosticArray`` with one status and its key/value pairs."""
    kv = T["diagnostic_msgs/msg/KeyValue"]
    status = T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[kv(key=str(k), value=str(v)) for k, v in values],
    )
    return T["diagnostic_msgs/msg/DiagnosticArray"](header=_header(T, t, ""), status=[status])


def reset_pose(msg) -> tuple[float, np.ndarray, np.ndarray]:
    """``geometry_msgs/PoseWithCovarianceStamped`` (robot_localization's ``set_pose``) ->
    ``(t, [x, y, theta], (3, 3) covariance)``; a covariance that is unknown (all zero) gives
    a zero matrix (the config's ``initial.sigma`` then applies)."""
    p = msg.pose.pose
    pose = np.array([p.position.x, p.position.y, ros_msgs.yaw(p.orientation)])
    _finite(pose, what="reset pose")
    _psd(msg.pose.covariance, 6, "reset pose covariance")
    C = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
    return ros_msgs.stamp(msg, 0), pose, C[np.ix_((0, 1, 5), (0, 1, 5))]
