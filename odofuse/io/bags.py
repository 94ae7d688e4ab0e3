"""ROS 2 bags (sqlite3 ``.db3`` or MCAP storage) and ROS 1 bags via ``rosbags.highlevel.AnyReader``.

This module reads bags: it chooses the topics, names the streams, checks message frames
against ``/tf_static`` and assembles the ``SensorLog``. What each message type means is
:mod:`odofuse.io.ros_msgs`.

==============================  ===========  ==================================================
message type                    stream       columns
==============================  ===========  ==================================================
``sensor_msgs/msg/JointState``  ``wheels``   one column per joint (or per ``joints`` entry):
                                             ``position`` (rad), or ``velocity`` integrated
``nav_msgs/msg/Odometry``       ``odometry`` ``ds, dtheta`` [+ ``var_ds, var_dtheta``]
``sensor_msgs/msg/Imu``         ``gyro``     ``wz`` [+ ``sigma``]; and ``compass``:
                                             ``heading, sigma`` where the orientation is valid
``sensor_msgs/msg/NavSatFix``   ``gps``      ``lat, lon`` (deg) [+ ``sigma`` (m)]
==============================  ===========  ==================================================

Time stamps are the message ``header.stamp`` (the bag receive time when the stamp is zero).
Topics come from ``topics`` (``{kind: topic or [topics]}``, the config's ``log.topics``) or,
for kinds not named there, from the one topic of the matching message type (two candidate
topics of one type without a mapping is an error that lists them). The k-th topic of a kind
(k >= 2) becomes stream ``<kind>_<k>`` (``gyro: [/imu/data, /imu2/data]`` -> ``gyro`` and
``gyro_2``, with ``compass`` and ``compass_2`` from their orientations).

Frames: when the bag has ``/tf_static``, the ``header.frame_id`` of every Imu and NavSatFix
message must be the base frame (the Odometry ``child_frame_id``, else ``base_link``), empty, or
a frame connected to it in ``/tf_static``; another frame is a one-line error. The planar pose of
each sensor frame in the base frame is kept in ``SensorLog.ros["mounts"]`` (GPS lever arms);
an IMU's yaw offset is removed from its compass headings here. Without ``/tf_static``, frames
are not checked and offsets come only from the config.

Odometry increments: for consecutive poses ``p_{k-1}, p_k`` (``pose.pose``, yaw from the
quaternion), ``d = p_{k-1}^-1 p_k`` in the child (body) frame; ``ds = sign(d_x) |(d_x, d_y)|``
and ``dtheta = wrap(d_theta)``, stamped at ``t_k`` (so N messages give N - 1 rows), the form of
the Plaza ``DR`` stream.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from odofuse.errors import InputError
from odofuse.io import cdr, ros_msgs
from odofuse.io.log import SensorLog, Stream
from odofuse.io.ros_msgs import odometry_increments  # noqa: F401  (public, used by tests)

MSG_STREAMS = {
    "sensor_msgs/msg/JointState": "wheels",
    "nav_msgs/msg/Odometry": "odometry",
    "sensor_msgs/msg/Imu": "gyro",
    "sensor_msgs/msg/NavSatFix": "gps",
}
STREAM_MSGS = {v: k for k, v in MSG_STREAMS.items()}
TF_STATIC = "/tf_static"
TF_TYPE = "tf2_msgs/msg/TFMessage"
DEFAULT_BASE_FRAME = "base_link"


def _normalise_type(msgtype: str) -> str:
    # ROS 1 bags name types "sensor_msgs/Imu"; ROS 2 "sensor_msgs/msg/Imu".
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[-1]}" if len(parts) == 2 else msgtype


def stream_name(kind: str, k: int) -> str:
    """Stream name of the k-th (0-based) topic of a kind: ``gyro``, ``gyro_2``, ..."""
    return kind if k == 0 else f"{kind}_{k + 1}"


def _kind(stream: str) -> str:
    """The kind of a stream name (``gyro_2`` -> ``gyro``)."""
    return stream.rsplit("_", 1)[0] if stream[-1].isdigit() else stream


def _decoded(reader, msgtype: str, bag_ns: list, data: list, columnar: bool) -> tuple:
    """``(t, columns)`` of one stream's messages (:func:`ros_msgs.columns`), or ``(None,
    messages)`` for ``/tf_static``: decoded at once when ``columnar`` and they share one CDR
    layout (:func:`odofuse.io.cdr.decode`), else message by message."""
    if msgtype == TF_TYPE:
        return None, [reader.deserialize(d, msgtype) for d in data]
    if columnar and reader.is2:
        stamp = ("header.stamp.sec", "header.stamp.nanosec")
        cols = cdr.decode(data, msgtype, reader.typestore, ros_msgs.FIELDS[msgtype] + stamp)
        if cols is not None:
            return ros_msgs.stamps(cols.pop(stamp[0]), cols.pop(stamp[1]), bag_ns), cols
    msgs = [reader.deserialize(d, msgtype) for d in data]
    t = np.array([ros_msgs.stamp(m, ns) for m, ns in zip(msgs, bag_ns, strict=True)])
    return t, ros_msgs.columns(msgs, msgtype)


def _choose_topics(reader, topics: dict | None, source: str) -> dict[str, tuple[str, list]]:
    """``{stream: (topic, [connections])}`` for every stream we can read."""
    topics = dict(topics or {})
    by_topic: dict[str, list] = {}
    for c in reader.connections:
        by_topic.setdefault(c.topic, []).append(c)
    chosen: dict[str, tuple[str, list]] = {}
    for kind, wanted in topics.items():
        if kind not in STREAM_MSGS:
            raise InputError(
                f"cannot read stream '{kind}' from a bag (readable: {', '.join(STREAM_MSGS)})",
                source,
                column=f"log.topics.{kind}",
            )
        for k, topic in enumerate([wanted] if isinstance(wanted, str) else list(wanted)):
            if topic not in by_topic:
                raise InputError(
                    f"topic '{topic}' (for {kind}) is not in the bag; topics: "
                    f"{', '.join(sorted(by_topic))}",
                    source,
                )
            conns = by_topic[topic]
            want = STREAM_MSGS[kind]
            if _normalise_type(conns[0].msgtype) != want:
                raise InputError(
                    f"topic '{topic}' has type {conns[0].msgtype}, {kind} needs {want}", source
                )
            chosen[stream_name(kind, k)] = (topic, conns)
    for kind, want in STREAM_MSGS.items():
        if kind in topics:
            continue
        cands = sorted(t for t, cs in by_topic.items() if _normalise_type(cs[0].msgtype) == want)
        if len(cands) > 1:
            raise InputError(
                f"several {want} topics ({', '.join(cands)}); choose one with "
                f"log: {{topics: {{{kind}: TOPIC}}}} in the config (or a list of topics: "
                f"{kind}, {kind}_2, ...)",
                source,
            )
        if cands:
            chosen[kind] = (cands[0], by_topic[cands[0]])
    tf = by_topic.get(TF_STATIC)
    if tf and _normalise_type(tf[0].msgtype) == TF_TYPE:
        chosen[TF_STATIC] = (TF_STATIC, tf)
    return chosen


def read_bag(
    path: str | Path, topics: dict | None = None, joints: dict | None = None, columnar: bool = True
) -> SensorLog:
    """Read a ROS 2 bag folder (``.db3`` or MCAP storage), a ``.mcap``/``.db3`` file inside one,
    or a ROS 1 ``.bag`` into a ``SensorLog``.

    Parameters
    ----------
    path : str or Path
        The bag.
    topics : dict, optional
        ``{kind: topic or [topics]}`` overriding the defaults by message type.
    joints : dict, optional
        ``{drive input name: joint name}`` for the JointState streams (``log.joints``).
    columnar : bool
        Decode each topic's ROS 2 messages at once where they share one layout
        (:mod:`odofuse.io.cdr`, the same numbers); False decodes message by message, as a
        ROS 1 bag always is (the reference the tests compare it with).

    Returns
    -------
    SensorLog
        Repairs: ``<stream>.reordered`` (messages sorted by header stamp),
        ``gps.no_fix_dropped`` (NavSatFix with status < 0 or non-finite lat/lon),
        ``<stream>.velocity_integrated`` (wheel angles integrated from JointState velocity).
        ``ros``: ``base_frame``, ``odom_frame`` (from Odometry, or None), ``frames``
        (stream -> frame_id), ``mounts`` (stream -> ``[x, y, yaw]`` of its frame in the base
        frame, from ``/tf_static``) and ``message_noise`` (stream -> columns taken from
        message covariances).
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
    raw: dict[str, tuple] = {}
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            chosen = _choose_topics(reader, topics, source)
            conn_stream = {c.id: s for s, (_, cs) in chosen.items() for c in cs}
            conns = [c for _, cs in chosen.values() for c in cs]
            payloads: dict[str, tuple[list, list]] = {}
            for conn, bag_ns, data in reader.messages(connections=conns):
                stream = payloads.setdefault(conn_stream[conn.id], ([], []))
                stream[0].append(bag_ns)
                stream[1].append(data)
            for stream, (bag_ns, data) in payloads.items():
                msgtype = STREAM_MSGS.get(_kind(stream), TF_TYPE)
                raw[stream] = _decoded(reader, msgtype, bag_ns, data, columnar)
    except InputError:
        raise
    except Exception as exc:  # rosbags raises its own error types for unreadable bags
        raise InputError(f"cannot read bag: {exc}", source) from None
    edges = ros_msgs.tf_edges(raw.pop(TF_STATIC, (None, []))[1])
    ros = _frames(raw, chosen, edges, source)
    repairs: dict[str, int] = {}
    streams: dict[str, Stream] = {}
    for stream, (t, cols) in raw.items():
        order = np.argsort(t, kind="stable")
        moved = np.count_nonzero(order != np.arange(t.size))
        if moved:
            repairs[f"{stream}.reordered"] = int(moved)
            t = t[order]
            cols = {
                k: v[order] if isinstance(v, np.ndarray) else [v[i] for i in order]
                for k, v in cols.items()
            }
        ctx = (source, chosen[stream][0], repairs, joints, ros)
        for s in _convert(stream, t, cols, ctx):
            if len(s):
                streams[s.name] = s
    if not streams:
        raise InputError(
            "no readable topics (JointState, Odometry, Imu, NavSatFix) in the bag", source
        )
    return SensorLog(source, streams, {}, None, repairs, ros=ros)


def _frames(raw: dict, chosen: dict, edges: dict, source: str) -> dict:
    """Base/odom frames, each sensor stream's frame and, with ``/tf_static``, its mount."""
    odom = next((raw[s][1] for s in raw if _kind(s) == "odometry" and len(raw[s][0])), None)
    base = (odom["child_frame_id"][0].lstrip("/") if odom else "") or DEFAULT_BASE_FRAME
    ros: dict = {
        "base_frame": base,
        "odom_frame": (odom["header.frame_id"][0].lstrip("/") or None) if odom else None,
        "frames": {},
        "mounts": {},
        "message_noise": {},
        "tf_static": bool(edges),
    }
    for stream, (t, cols) in raw.items():
        if _kind(stream) not in ("gyro", "gps") or not len(t):
            continue
        topic = chosen[stream][0]
        frames = sorted({f.lstrip("/") for f in cols["header.frame_id"]})
        if len(frames) > 1:
            raise InputError(
                f"topic {topic}: messages in several frames ({', '.join(frames)})", source
            )
        frame = frames[0]
        ros["frames"][stream] = frame or base
        if not edges or frame in ("", base):
            continue
        mount = ros_msgs.frame_in(edges, frame, base)
        if mount is None:
            known = sorted({base, *edges, *(p for p, _ in edges.values())})
            raise InputError(
                f"topic {topic}: frame '{frame}' is not connected to '{base}' in /tf_static "
                f"(frames: {', '.join(known)})",
                source,
            )
        ros["mounts"][stream] = [float(v) for v in mount]
    return ros


def _convert(stream: str, t: np.ndarray, cols: dict, ctx) -> list[Stream]:
    source, topic, repairs, joints, ros = ctx
    kind = _kind(stream)
    suffix = stream[len(kind) :]
    noise = ros["message_noise"]
    if kind == "wheels":
        names, vals = ros_msgs.joint_columns(t, cols, joints, source, topic, repairs, stream)
        return [Stream(stream, source, t, names, vals)]
    if kind == "odometry":
        if len(t) < 2:
            return []
        ti, names, vals = ros_msgs.odometry_columns(t, cols)
        if "var_ds" in names:
            noise[stream] = ["var_ds", "var_dtheta"]
        return [Stream(stream, source, ti, names, vals)]
    if kind == "gyro":
        yaw_offset = ros["mounts"].get(stream, [0.0, 0.0, 0.0])[2]
        (gcols, gvals), compass = ros_msgs.imu_columns(cols, yaw_offset)
        out = [Stream(stream, source, t, gcols, gvals)]
        if "sigma" in gcols:
            noise[stream] = ["sigma"]
        if compass is not None:
            ccols, cvals, keep = compass
            name = f"compass{suffix}"
            out.append(Stream(name, source, t[keep], ccols, cvals))
            noise[name] = ["sigma"]
            ros["frames"][name] = ros["frames"].get(stream, ros["base_frame"])
        return out
    if kind == "gps":
        names, vals, keep = ros_msgs.navsat_columns(cols)
        if not keep.all():
            repairs[f"{stream}.no_fix_dropped"] = int(np.count_nonzero(~keep))
        if "sigma" in names:
            noise[stream] = ["sigma"]
        return [Stream(stream, source, t[keep], names, vals)]
    return []  # pragma: no cover
