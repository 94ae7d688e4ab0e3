"""ROS 2 bags (sqlite3 ``.db3`` or MCAP storage) and ROS 1 bags via ``rosbags.highlevel.AnyReader``.

Message types map to the streams of a log folder (shared spec section 1):

==============================  ===========  ==================================================
message type                    stream       columns
==============================  ===========  ==================================================
``sensor_msgs/msg/JointState``  ``wheels``   one column per joint name: ``position`` (rad), or
                                             ``velocity`` (rad/s) with ``joint_field``
``nav_msgs/msg/Odometry``       ``odometry`` ``ds, dtheta``: increment between consecutive poses
``sensor_msgs/msg/Imu``         ``gyro``     ``wz`` = ``angular_velocity.z`` (rad/s)
``sensor_msgs/msg/NavSatFix``   ``gps``      ``lat, lon`` (deg), ``sigma`` (m) from the covariance
==============================  ===========  ==================================================

Time stamps are the message ``header.stamp`` (the bag receive time when the stamp is zero).
Topics come from ``topics`` (``{stream: topic}``, the config's ``log.topics``) or, for streams
not named there, from the one topic of the matching message type (two candidate topics of one
type without a mapping is an error that lists them).

Odometry increments: for consecutive poses ``p_{k-1}, p_k`` (``pose.pose``, yaw from the
quaternion), ``d = p_{k-1}^-1 p_k`` in the child (body) frame; ``ds = sign(d_x) |(d_x, d_y)|``
and ``dtheta = wrap(d_theta)``, stamped at ``t_k`` (so N messages give N - 1 rows), the form of
the Plaza ``DR`` stream.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse.errors import InputError
from odofuse.io.log import SensorLog, Stream
from odofuse.se2 import wrap

MSG_STREAMS = {
    "sensor_msgs/msg/JointState": "wheels",
    "nav_msgs/msg/Odometry": "odometry",
    "sensor_msgs/msg/Imu": "gyro",
    "sensor_msgs/msg/NavSatFix": "gps",
}
STREAM_MSGS = {v: k for k, v in MSG_STREAMS.items()}


def _normalise_type(msgtype: str) -> str:
    # ROS 1 bags name types "sensor_msgs/Imu"; ROS 2 "sensor_msgs/msg/Imu".
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[-1]}" if len(parts) == 2 else msgtype


def _stamp(msg, bag_ns: int) -> float:
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


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


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
    return np.asarray(t, dtype=float)[1:], np.column_stack([ds, wrap(np.diff(p[:, 2]))])


def _choose_topics(reader, topics: dict | None, source: str) -> dict[str, object]:
    """{stream: [connections]} for every stream we can read."""
    topics = dict(topics or {})
    by_topic: dict[str, list] = {}
    for c in reader.connections:
        by_topic.setdefault(c.topic, []).append(c)
    chosen: dict[str, list] = {}
    for stream, topic in topics.items():
        if stream not in STREAM_MSGS:
            raise InputError(
                f"cannot read stream '{stream}' from a bag (readable: {', '.join(STREAM_MSGS)})",
                source,
                column=f"log.topics.{stream}",
            )
        if topic not in by_topic:
            raise InputError(
                f"topic '{topic}' (for {stream}) is not in the bag; topics: "
                f"{', '.join(sorted(by_topic))}",
                source,
            )
        conns = by_topic[topic]
        want = STREAM_MSGS[stream]
        if _normalise_type(conns[0].msgtype) != want:
            raise InputError(
                f"topic '{topic}' has type {conns[0].msgtype}, {stream} needs {want}", source
            )
        chosen[stream] = conns
    for stream, want in STREAM_MSGS.items():
        if stream in chosen:
            continue
        cands = sorted(t for t, cs in by_topic.items() if _normalise_type(cs[0].msgtype) == want)
        if len(cands) > 1:
            raise InputError(
                f"several {want} topics ({', '.join(cands)}); choose one with "
                f"log: {{topics: {{{stream}: TOPIC}}}} in the config",
                source,
            )
        if cands:
            chosen[stream] = by_topic[cands[0]]
    return chosen


def read_bag(
    path: str | Path, topics: dict | None = None, joint_field: str = "position"
) -> SensorLog:
    """Read a ROS 2 bag folder (``.db3`` or MCAP storage), a ``.mcap``/``.db3`` file inside one,
    or a ROS 1 ``.bag`` into a ``SensorLog``.

    Parameters
    ----------
    path : str or Path
        The bag.
    topics : dict, optional
        ``{stream: topic}`` overriding the defaults by message type.
    joint_field : {"position", "velocity"}
        The JointState array read into ``wheels`` (``log.wheel_inputs``).

    Returns
    -------
    SensorLog
        Repairs: ``<stream>.reordered`` (messages sorted by header stamp),
        ``gps.no_fix_dropped`` (NavSatFix with status < 0 or non-finite lat/lon).
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    source = str(path)
    if (
        path.is_file()
        and path.suffix in (".db3", ".mcap")
        and (path.parent / "metadata.yaml").exists()
    ):
        path = path.parent
    repairs: dict[str, int] = {}
    raw: dict[str, list] = {}
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            chosen = _choose_topics(reader, topics, source)
            conn_stream = {c.id: s for s, cs in chosen.items() for c in cs}
            conns = [c for cs in chosen.values() for c in cs]
            for conn, bag_ns, data in reader.messages(connections=conns):
                stream = conn_stream[conn.id]
                msg = reader.deserialize(data, conn.msgtype)
                raw.setdefault(stream, []).append((_stamp(msg, bag_ns), msg))
    except InputError:
        raise
    except Exception as exc:  # rosbags raises its own error types for unreadable bags
        raise InputError(f"cannot read bag: {exc}", source) from None
    streams: dict[str, Stream] = {}
    for stream, items in raw.items():
        t = np.array([s for s, _ in items])
        order = np.argsort(t, kind="stable")
        if np.any(order != np.arange(t.size)):
            repairs[f"{stream}.reordered"] = int(np.count_nonzero(order != np.arange(t.size)))
        items = [items[i] for i in order]
        s = _convert(stream, items, source, repairs, joint_field)
        if s is not None and len(s):
            streams[stream] = s
    if not streams:
        raise InputError(
            "no readable topics (JointState, Odometry, Imu, NavSatFix) in the bag", source
        )
    return SensorLog(source, streams, {}, None, repairs)


def _convert(
    stream: str, items, source: str, repairs: dict, joint_field: str = "position"
) -> Stream | None:
    t = np.array([s for s, _ in items])
    msgs = [m for _, m in items]
    if stream == "wheels":
        names = tuple(msgs[0].name)
        if not names:
            raise InputError("JointState without joint names", source, column="wheels")
        vals = np.empty((len(msgs), len(names)))
        for k, m in enumerate(msgs):
            array = np.asarray(getattr(m, joint_field), dtype=float)
            pos = dict(zip(m.name, array, strict=False))
            try:
                vals[k] = [pos[n] for n in names]
            except KeyError as exc:
                raise InputError(
                    f"JointState message {k + 1} lacks joint {exc}", source, column="wheels"
                ) from None
        return Stream("wheels", source, t, names, vals)
    if stream == "odometry":
        if len(msgs) < 2:
            return None
        poses = np.array(
            [
                [m.pose.pose.position.x, m.pose.pose.position.y, _yaw(m.pose.pose.orientation)]
                for m in msgs
            ]
        )
        ti, inc = odometry_increments(t, poses)
        return Stream("odometry", source, ti, ("ds", "dtheta"), inc)
    if stream == "gyro":
        return Stream("gyro", source, t, ("wz",), np.array([[m.angular_velocity.z] for m in msgs]))
    if stream == "gps":
        keep = [
            k
            for k, m in enumerate(msgs)
            if m.status.status >= 0 and math.isfinite(m.latitude) and math.isfinite(m.longitude)
        ]
        if len(keep) < len(msgs):
            repairs["gps.no_fix_dropped"] = len(msgs) - len(keep)
        msgs = [msgs[k] for k in keep]
        t = t[keep]
        ll = np.array([[m.latitude, m.longitude] for m in msgs]).reshape(-1, 2)
        # covariance_type 0 = unknown; otherwise sigma = sqrt of the mean horizontal variance.
        known = [
            m.position_covariance_type != 0
            and m.position_covariance[0] > 0
            and m.position_covariance[4] > 0
            for m in msgs
        ]
        if msgs and all(known):
            sig = np.array(
                [
                    math.sqrt(0.5 * (m.position_covariance[0] + m.position_covariance[4]))
                    for m in msgs
                ]
            )
            return Stream("gps", source, t, ("lat", "lon", "sigma"), np.column_stack([ll, sig]))
        return Stream("gps", source, t, ("lat", "lon"), ll)
    return None  # pragma: no cover
