"""ROS message conversion: deserialised messages -> odofuse streams (arrays in SI units).

This module owns what one message type means: which fields become which columns, how ROS's
"unknown covariance" conventions are read, and the planar frame tree of ``/tf_static``.
Reading bags, choosing topics and naming streams is :mod:`odofuse.io.bags`.

Covariance conventions (REP-145 and the ``sensor_msgs`` message comments):

* an all-zero covariance means "unknown": no per-row noise column is made, so the sensor
  block's ``sigma`` (or the model default) applies;
* ``covariance[0] == -1`` means "this quantity is not provided": for ``Imu`` orientation no
  ``compass`` stream is made, for angular velocity no ``sigma`` column;
* ``NavSatFix.position_covariance_type == 0`` (``COVARIANCE_TYPE_UNKNOWN``) is unknown.
"""

from __future__ import annotations

import math
import operator

import numpy as np

from odofuse import se2
from odofuse.errors import InputError

IMU, NAVSAT = "sensor_msgs/msg/Imu", "sensor_msgs/msg/NavSatFix"
ODOMETRY, JOINT_STATE = "nav_msgs/msg/Odometry", "sensor_msgs/msg/JointState"
_QUATERNION = ("x", "y", "z", "w")
#: The fields odofuse reads of each message type, beside ``header.stamp`` (:func:`stamp`):
#: the columns the converters below take (:func:`columns`, or a bag's columnar decoding).
FIELDS = {
    JOINT_STATE: ("name", "position", "velocity"),
    ODOMETRY: (
        "header.frame_id",
        "child_frame_id",
        "pose.pose.position.x",
        "pose.pose.position.y",
        *(f"pose.pose.orientation.{c}" for c in _QUATERNION),
        "pose.covariance",
        "twist.covariance",
    ),
    IMU: (
        "header.frame_id",
        *(f"orientation.{c}" for c in _QUATERNION),
        "orientation_covariance",
        "angular_velocity.z",
        "angular_velocity_covariance",
    ),
    NAVSAT: (
        "header.frame_id",
        "status.status",
        "latitude",
        "longitude",
        "position_covariance",
        "position_covariance_type",
    ),
}
_TEXT = {"header.frame_id", "child_frame_id", "name"}


def columns(msgs, msgtype: str) -> dict:
    """The :data:`FIELDS` of deserialised messages ``msgs`` of ``msgtype`` as columns: numbers
    ``(N,)``, fixed arrays ``(N, k)``, sequences ``(N, k)`` when every message has k elements
    (else a list of arrays), strings a list of N strings, joint names a list of tuples."""
    out: dict = {}
    for path in FIELDS[msgtype]:
        values = list(map(_getters[path], msgs))
        if path in _TEXT:
            out[path] = [v if isinstance(v, str) else tuple(v) for v in values]
            continue
        try:
            out[path] = np.array(values, dtype=float)
        except ValueError:  # sequences of several lengths
            out[path] = [np.asarray(v, dtype=float) for v in values]
    return out


_getters = {p: operator.attrgetter(p) for paths in FIELDS.values() for p in paths}


def stamp(msg, bag_ns: int) -> float:
    """``header.stamp`` in seconds, or the bag receive time when the stamp is zero."""
    header = getattr(msg, "header", None)
    if header is not None:
        st = header.stamp
        sec = getattr(st, "sec", None)
        if sec is None:  # ROS 1 Time
            sec, nsec = st.secs, st.nsecs
        else:
            nsec = st.nanosec
        if sec or nsec:
            return sec + nsec * 1e-9
    return bag_ns * 1e-9


def stamps(sec, nanosec, bag_ns) -> np.ndarray:
    """:func:`stamp` of N messages from their ``header.stamp`` columns and receive times."""
    sec, nanosec = np.asarray(sec), np.asarray(nanosec)
    return np.where((sec != 0) | (nanosec != 0), sec + nanosec * 1e-9, np.asarray(bag_ns) * 1e-9)


def frame_of(msg) -> str:
    """``header.frame_id`` without a leading ``/`` (``""`` when the message has none)."""
    header = getattr(msg, "header", None)
    return str(getattr(header, "frame_id", "") or "").lstrip("/")


def yaw(q) -> float:
    """Yaw (rad) of a ``geometry_msgs/Quaternion`` (ZYX convention)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _yaws(cols: dict, prefix: str, keep=None) -> np.ndarray:
    """:func:`yaw` of the quaternion columns ``<prefix>x .. <prefix>w`` (rows ``keep``), with
    the same floating-point operations (``math.atan2`` on each row)."""
    x, y, z, w = (np.asarray(cols[prefix + c], dtype=float) for c in _QUATERNION)
    if keep is not None:
        x, y, z, w = x[keep], y[keep], z[keep], w[keep]
    num, den = 2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)
    return np.array([math.atan2(a, b) for a, b in zip(num.tolist(), den.tolist(), strict=True)])


def _unknown(cov) -> np.ndarray:
    """Per row of covariances ``(N, k)``: unknown (all zero) or not provided (``[0] == -1``)."""
    c = np.asarray(cov, dtype=float)
    if c.shape[-1] == 0:
        return np.ones(len(c), dtype=bool)
    return (c[:, 0] == -1.0) | ~c.any(axis=1)


def odometry_increments(t, poses) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame increments ``(ds, dtheta)`` between consecutive poses.

    Parameters
    ----------
    t : array_like, shape (N,)
        Time stamps (s).
    poses : array_like, shape (N, 3)
        ``[x, y, theta]`` in the odometry frame.

    Returns
    -------
    t : ndarray, shape (N - 1,)
        ``t[1:]``.
    inc : ndarray, shape (N - 1, 2)
        ``ds = sign(dx) * hypot(dx, dy)`` (m) and ``dtheta`` (rad, wrapped), with
        ``(dx, dy, dtheta) = p_{k-1}^-1 p_k``.
    """
    p = np.asarray(poses, dtype=float)
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    ddx, ddy = np.diff(p[:, 0]), np.diff(p[:, 1])
    dx = c * ddx + s * ddy
    dy = -s * ddx + c * ddy
    ds = np.where(dx < 0, -1.0, 1.0) * np.hypot(dx, dy)
    return np.asarray(t, dtype=float)[1:], np.column_stack([ds, se2.wrap(np.diff(p[:, 2]))])


def odometry_columns(t, cols: dict) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """``nav_msgs/Odometry`` columns (:func:`columns`) -> increments, with their variances
    when the messages give them.

    ``var_ds = var(v_x) dt^2`` and ``var_dtheta = var(omega_z) dt^2`` from the twist covariance
    (child frame, indices 0 and 35) over each message interval ``dt``; when the twist covariance
    is unknown (all zero), the growth of the pose covariance between the two messages (along
    the heading, and of yaw, clipped at 0) is used; when both are unknown, or the pose
    covariance does not grow (a constant, as ``diff_drive_controller`` publishes it), no
    variance columns are made.

    Returns
    -------
    t : ndarray (N - 1,)
    columns : tuple of str
        ``("ds", "dtheta")`` or ``("ds", "dtheta", "var_ds", "var_dtheta")``.
    values : ndarray (N - 1, C)
    """
    xy = [np.asarray(cols[f"pose.pose.position.{c}"], dtype=float) for c in "xy"]
    poses = np.column_stack([*xy, _yaws(cols, "pose.pose.orientation.")])
    ti, inc = odometry_increments(t, poses)
    dt = np.diff(np.asarray(t, dtype=float))
    twist = np.asarray(cols["twist.covariance"], dtype=float)
    if not np.any(_unknown(twist[1:])):
        var = twist[1:][:, [0, 35]] * (dt**2)[:, None]
    else:
        P = np.asarray(cols["pose.covariance"], dtype=float).reshape(-1, 6, 6)
        dP = np.diff(P, axis=0)
        c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
        along = c * c * dP[:, 0, 0] + 2 * c * s * dP[:, 0, 1] + s * s * dP[:, 1, 1]
        var = np.column_stack([along, dP[:, 5, 5]])
        if not np.all(var > 0):
            return ti, ("ds", "dtheta"), inc
    return ti, ("ds", "dtheta", "var_ds", "var_dtheta"), np.column_stack([inc, var])


def joint_columns(
    t,
    cols: dict,
    joints: dict[str, str] | None,
    source: str,
    topic: str,
    repairs: dict,
    stream: str,
) -> tuple[tuple[str, ...], np.ndarray]:
    """``sensor_msgs/JointState`` columns (:func:`columns`) -> cumulative joint angles (rad),
    one column per joint.

    Parameters
    ----------
    t : ndarray (N,)
        Message times (s).
    cols : dict
        The messages' ``name``, ``position`` and ``velocity`` (joint order may change between
        messages: joints are matched by name).
    joints : dict or None
        ``{column: joint name}`` (the config's ``log.joints``, e.g. ``{left: left_wheel_joint}``);
        ``None``: one column per joint of the first message, named after the joint.
    repairs : dict
        Gets ``<stream>.velocity_integrated`` (the number of messages) when the angles come
        from ``velocity``: used when ``position`` is empty in any message, integrated with the
        trapezoidal rule over each message interval, starting at 0.

    Returns
    -------
    columns : tuple of str
    values : ndarray (N, C)
    """
    names_of = cols["name"]
    names = tuple(names_of[0])
    if not names:
        raise InputError(f"JointState on {topic} has no joint names", source, column=stream)
    if joints:
        missing = [j for j in joints.values() if j not in names]
        if missing:
            key = next(k for k, j in joints.items() if j == missing[0])
            raise InputError(
                f"joint '{missing[0]}' (log.joints.{key}) is not in the JointState on {topic} "
                f"(joints: {', '.join(names)})",
                source,
                column=f"log.joints.{key}",
            )
        columns_, wanted = tuple(joints), tuple(joints.values())
    else:
        columns_ = wanted = names
    use_velocity = any(len(p) == 0 for p in cols["position"])
    field = "velocity" if use_velocity else "position"
    data, vals = cols[field], None
    if isinstance(data, np.ndarray) and all(n == names for n in names_of):
        # every message has these joints in this order: one lookup (the loop's zip and dict)
        index = dict(zip(names, range(data.shape[1]), strict=False))
        if all(n in index for n in wanted):  # else the loop names the first message
            vals = data[:, [index[n] for n in wanted]].astype(float)
    if vals is None:
        vals = np.empty((len(names_of), len(wanted)))
        for k, (msg_names, values) in enumerate(zip(names_of, data, strict=True)):
            row = dict(zip(msg_names, np.asarray(values, dtype=float), strict=False))
            try:
                vals[k] = [row[n] for n in wanted]
            except KeyError as exc:
                raise InputError(
                    f"JointState message {k + 1} on {topic} has no {field} for joint {exc}",
                    source,
                    column=stream,
                ) from None
    if use_velocity:
        dt = np.diff(np.asarray(t, dtype=float))
        steps = 0.5 * (vals[1:] + vals[:-1]) * dt[:, None]
        vals = np.vstack([np.zeros((1, len(wanted))), np.cumsum(steps, axis=0)])
        repairs[f"{stream}.velocity_integrated"] = len(names_of)
    return columns_, vals


def imu_columns(cols: dict, yaw_offset: float = 0.0):
    """``sensor_msgs/Imu`` columns (:func:`columns`) -> gyro rows and, where the orientation
    is valid, compass rows.

    Parameters
    ----------
    cols : dict
    yaw_offset : float
        Yaw of the IMU frame in the robot's base frame (rad, from ``/tf_static``): the
        robot's heading is the IMU's yaw minus it. The yaw rate of a planar robot is the
        same in both frames.

    Returns
    -------
    gyro : (columns, values)
        ``("wz",)`` or ``("wz", "sigma")``: ``sigma = sqrt(angular_velocity_covariance[8])``
        (rad/s) when every message gives it (not unknown, not -1).
    compass : (columns, values, keep) or None
        ``("heading",)`` or ``("heading", "sigma")`` (``sigma = sqrt(orientation_covariance[8])``),
        and the boolean mask of the messages that carry an orientation: a message whose
        ``orientation_covariance[0] == -1`` or whose covariance is all zero (unknown, as a 6-axis
        IMU without magnetometer publishes) or whose quaternion is zero has none. ``None`` when
        no message has one.
    """
    wz = np.asarray(cols["angular_velocity.z"], dtype=float).reshape(-1, 1)
    av = np.asarray(cols["angular_velocity_covariance"], dtype=float)
    if len(wz) and not (_unknown(av) | (av[:, 8] <= 0)).any():
        gyro = (("wz", "sigma"), np.concatenate([wz, np.sqrt(av[:, 8:9])], axis=1))
    else:
        gyro = (("wz",), wz)
    oc = np.asarray(cols["orientation_covariance"], dtype=float)
    x, y, z, w = (np.asarray(cols[f"orientation.{c}"], dtype=float) for c in _QUATERNION)
    keep = ~_unknown(oc) & (oc[:, 8] > 0) & ((x != 0) | (y != 0) | (z != 0) | (w != 0))
    if not keep.any():
        return gyro, None
    heading = se2.wrap(_yaws(cols, "orientation.", keep) - yaw_offset)
    sigma = np.sqrt(oc[keep, 8])
    return gyro, (("heading", "sigma"), np.concatenate([heading[:, None], sigma[:, None]], 1), keep)


def navsat_columns(cols: dict):
    """``sensor_msgs/NavSatFix`` columns (:func:`columns`) -> ``lat, lon`` (deg) [+ ``sigma``
    (m)] and the kept mask.

    Fixes with ``status.status < 0`` (no fix) or non-finite lat/lon are dropped (mask False).
    ``sigma = sqrt((c_ee + c_nn) / 2)`` of the ENU ``position_covariance`` when every kept fix
    has a known one (``position_covariance_type`` 1 approximated, 2 diagonal known or 3 known,
    and positive east/north variances).
    """
    lat, lon = (np.asarray(cols[c], dtype=float) for c in ("latitude", "longitude"))
    keep = (np.asarray(cols["status.status"]) >= 0) & np.isfinite(lat) & np.isfinite(lon)
    ll = np.column_stack([lat[keep], lon[keep]])
    pc = np.asarray(cols["position_covariance"], dtype=float)[keep]
    known = (np.asarray(cols["position_covariance_type"])[keep] != 0) & (pc[:, 0] > 0)
    if keep.any() and np.all(known & (pc[:, 4] > 0)):
        sig = np.sqrt(0.5 * (pc[:, 0] + pc[:, 4]))
        return ("lat", "lon", "sigma"), np.column_stack([ll, sig]), keep
    return ("lat", "lon"), ll, keep


def tf_edges(msgs) -> dict[str, tuple[str, np.ndarray]]:
    """``tf2_msgs/TFMessage`` (``/tf_static``) -> ``{child: (parent, planar pose in parent)}``.

    Each transform becomes ``[x, y, yaw]`` of the child frame in the parent frame (z, roll and
    pitch are dropped: the estimate is planar).
    """
    edges: dict[str, tuple[str, np.ndarray]] = {}
    for m in msgs:
        for tf in m.transforms:
            tr, q = tf.transform.translation, tf.transform.rotation
            child = str(tf.child_frame_id).lstrip("/")
            edges[child] = (
                str(tf.header.frame_id).lstrip("/"),
                np.array([tr.x, tr.y, yaw(q)], dtype=float),
            )
    return edges


def frame_in(edges: dict[str, tuple[str, np.ndarray]], frame: str, base: str) -> np.ndarray | None:
    """Planar pose ``[x, y, yaw]`` of ``frame`` in ``base`` through the ``/tf_static`` tree.

    Both frames are walked up to their root; ``None`` when they are not in one tree.
    """

    def chain(f):
        pose, seen = np.zeros(3), {f}
        while f in edges:
            parent, rel = edges[f]
            pose = se2.compose(rel, pose)
            f = parent
            if f in seen:  # a cycle: not a tree
                return None, None
            seen.add(f)
        return f, pose

    root_f, pose_f = chain(frame)
    root_b, pose_b = chain(base)
    if root_f is None or root_b is None or root_f != root_b:
        return None
    return se2.compose(se2.inverse(pose_b), pose_f)
