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

import numpy as np

from odofuse import se2
from odofuse.errors import InputError


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


def frame_of(msg) -> str:
    """``header.frame_id`` without a leading ``/`` (``""`` when the message has none)."""
    header = getattr(msg, "header", None)
    return str(getattr(header, "frame_id", "") or "").lstrip("/")


def yaw(q) -> float:
    """Yaw (rad) of a ``geometry_msgs/Quaternion`` (ZYX convention)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _unknown(cov) -> bool:
    c = np.asarray(cov, dtype=float)
    return c.size == 0 or c[0] == -1.0 or not np.any(c)


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


def odometry_columns(t, msgs) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """``nav_msgs/Odometry`` -> increments, with their variances when the messages give them.

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
    poses = np.array(
        [
            [m.pose.pose.position.x, m.pose.pose.position.y, yaw(m.pose.pose.orientation)]
            for m in msgs
        ]
    )
    ti, inc = odometry_increments(t, poses)
    dt = np.diff(np.asarray(t, dtype=float))
    twist = [np.asarray(m.twist.covariance, dtype=float) for m in msgs]
    if not any(_unknown(c) for c in twist[1:]):
        var = np.array([[c[0], c[35]] for c in twist[1:]]) * (dt**2)[:, None]
    else:
        P = np.array([np.asarray(m.pose.covariance, dtype=float).reshape(6, 6) for m in msgs])
        dP = np.diff(P, axis=0)
        c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
        along = c * c * dP[:, 0, 0] + 2 * c * s * dP[:, 0, 1] + s * s * dP[:, 1, 1]
        var = np.column_stack([along, dP[:, 5, 5]])
        if not np.all(var > 0):
            return ti, ("ds", "dtheta"), inc
    return ti, ("ds", "dtheta", "var_ds", "var_dtheta"), np.column_stack([inc, var])


def joint_columns(
    t, msgs, joints: dict[str, str] | None, source: str, topic: str, repairs: dict, stream: str
) -> tuple[tuple[str, ...], np.ndarray]:
    """``sensor_msgs/JointState`` -> cumulative joint angles (rad), one column per joint.

    Parameters
    ----------
    t : ndarray (N,)
        Message times (s).
    msgs : list
        The messages (joint order may change between them: joints are matched by name).
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
    names = tuple(msgs[0].name)
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
        columns, wanted = tuple(joints), tuple(joints.values())
    else:
        columns = wanted = names
    use_velocity = any(len(m.position) == 0 for m in msgs)
    field = "velocity" if use_velocity else "position"
    vals = np.empty((len(msgs), len(wanted)))
    for k, m in enumerate(msgs):
        data = dict(zip(m.name, np.asarray(getattr(m, field), dtype=float), strict=False))
        try:
            vals[k] = [data[n] for n in wanted]
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
        repairs[f"{stream}.velocity_integrated"] = len(msgs)
    return columns, vals


def imu_columns(msgs, yaw_offset: float = 0.0):
    """``sensor_msgs/Imu`` -> gyro rows and, where the orientation is valid, compass rows.

    Parameters
    ----------
    msgs : list
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
    wz = np.array([[m.angular_velocity.z] for m in msgs]).reshape(-1, 1)
    av = [np.asarray(m.angular_velocity_covariance, dtype=float) for m in msgs]
    if msgs and not any(_unknown(c) or c[8] <= 0 for c in av):
        gyro = (("wz", "sigma"), np.column_stack([wz, np.sqrt([c[8] for c in av])]))
    else:
        gyro = (("wz",), wz)
    oc = [np.asarray(m.orientation_covariance, dtype=float) for m in msgs]
    q = [m.orientation for m in msgs]
    keep = np.array(
        [
            not _unknown(c) and c[8] > 0 and (qq.x, qq.y, qq.z, qq.w) != (0.0, 0.0, 0.0, 0.0)
            for c, qq in zip(oc, q, strict=True)
        ],
        dtype=bool,
    )
    if not keep.any():
        return gyro, None
    heading = se2.wrap(np.array([yaw(qq) for qq, k in zip(q, keep, strict=True) if k]) - yaw_offset)
    sig = np.sqrt([c[8] for c, k in zip(oc, keep, strict=True) if k])
    return gyro, (("heading", "sigma"), np.column_stack([heading, sig]), keep)


def navsat_columns(msgs):
    """``sensor_msgs/NavSatFix`` -> ``lat, lon`` (deg) [+ ``sigma`` (m)] and the kept mask.

    Fixes with ``status.status < 0`` (no fix) or non-finite lat/lon are dropped (mask False).
    ``sigma = sqrt((c_ee + c_nn) / 2)`` of the ENU ``position_covariance`` when every kept fix
    has a known one (``position_covariance_type`` 1 approximated, 2 diagonal known or 3 known,
    and positive east/north variances).
    """
    keep = np.array(
        [
            m.status.status >= 0 and math.isfinite(m.latitude) and math.isfinite(m.longitude)
            for m in msgs
        ],
        dtype=bool,
    )
    kept = [m for m, k in zip(msgs, keep, strict=True) if k]
    ll = np.array([[m.latitude, m.longitude] for m in kept]).reshape(-1, 2)
    known = [
        m.position_covariance_type != 0
        and m.position_covariance[0] > 0
        and m.position_covariance[4] > 0
        for m in kept
    ]
    if kept and all(known):
        sig = np.sqrt([0.5 * (m.position_covariance[0] + m.position_covariance[4]) for m in kept])
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
