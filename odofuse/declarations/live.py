"""Declaration of the ``live:`` block: ``odofuse live`` (the streaming Localizer behind ROS 2
topics over Zenoh, :mod:`odofuse.live`).

Every key is optional: a config without ``live:`` runs as it is, in Zenoh peer mode, on the
input topics and joint mapping its ``log:`` block gives for a bag, publishing on
robot_localization's default topics in Jazzy's wire format. rmw_zenoh's own environment
variables apply as they do to a ROS 2 node (``ZENOH_SESSION_CONFIG_URI``,
``ZENOH_CONFIG_OVERRIDE``, ``ROS_DOMAIN_ID``); the keys here override them.
"""

from __future__ import annotations

from dataclasses import dataclass

from odofuse.declarations.common import _NONNEG, _POSITIVE
from odofuse.options import option

#: ROS 2 distributions whose wire format ``odofuse live`` speaks (Humble: no type hashes).
DISTROS = ("humble", "jazzy", "kilted", "rolling")
#: Zenoh session modes.
ZENOH_MODES = ("peer", "client", "router")
#: Input stream kinds a topic can feed (``topics:`` keys) and their message types.
INPUT_KINDS = {
    "wheels": "sensor_msgs/msg/JointState",
    "odometry": "nav_msgs/msg/Odometry",
    "gyro": "sensor_msgs/msg/Imu",
    "gps": "sensor_msgs/msg/NavSatFix",
    "twist": "geometry_msgs/msg/TwistStamped",
}
#: Default input topics (robot_localization's and the common drivers' names).
DEFAULT_TOPICS = {
    "wheels": "/joint_states",
    "odometry": "/odom",
    "gyro": "/imu/data",
    "gps": "/fix",
    "twist": "/cmd_vel",
}
#: Output kinds (``outputs:`` keys) and their default topics (robot_localization's).
DEFAULT_OUTPUTS = {
    "odometry": "/odometry/filtered",
    "tf": "/tf",
    "tf_static": "/tf_static",
    "diagnostics": "/diagnostics",
    "reset": "/set_pose",
}


@dataclass(frozen=True)
class LiveOptions:
    """``live``: transport, topics, frames, QoS and wire format of ``odofuse live``."""

    transport: str = option(
        "zenoh", unit="-", doc="zenoh (rmw_zenoh's wire format) or none", choices=("zenoh", "none")
    )
    mode: str | None = option(
        None,
        unit="-",
        doc="Zenoh session mode; null: ZENOH_SESSION_CONFIG_URI's, else peer",
        choices=ZENOH_MODES,
    )
    connect: tuple[str, ...] | None = option(
        None,
        unit="-",
        doc="Zenoh endpoints to connect to (a router or peers); null: the session config's "
        "(rmw_zenoh's default: tcp/localhost:7447)",
    )
    listen: tuple[str, ...] | None = option(
        None, unit="-", doc="Zenoh endpoints to listen on; null: the session config's"
    )
    multicast_scouting: bool | None = option(
        None, unit="-", doc="UDP multicast scouting; null: the session config's (rmw_zenoh: off)"
    )
    domain_id: int | None = option(
        None, unit="-", doc="ROS domain id; null: ROS_DOMAIN_ID, else 0", minimum=0, maximum=232
    )
    distro: str = option(
        "jazzy", unit="-", doc="ROS 2 distribution whose wire format to speak", choices=DISTROS
    )
    node: str = option("odofuse", unit="-", doc="ROS node name (liveliness tokens)")
    namespace: str = option("", unit="-", doc="ROS namespace of the node and its topics")
    topics: dict[str, str | tuple[str, ...]] | None = option(
        None,
        unit="-",
        doc="input kind (wheels, odometry, gyro, gps, twist) -> topic or list; null: log.topics, "
        "else the bag's topic of that type, else /joint_states, /odom, /imu/data, /fix",
    )
    joints: dict[str, str] | None = option(
        None, unit="-", doc="drive input -> JointState joint name; null: log.joints"
    )
    outputs: dict[str, str] | None = option(
        None,
        unit="-",
        doc="output (odometry, tf, tf_static, diagnostics, reset) -> topic; null: "
        "/odometry/filtered, /tf, /tf_static, /diagnostics, /set_pose",
    )
    map_frame: str = option("map", unit="-", doc="REP-105 map frame id")
    odom_frame: str = option("odom", unit="-", doc="REP-105 odom frame id")
    base_frame: str | None = option(
        None, unit="-", doc="robot frame id; null: the bag's child_frame_id, else base_link"
    )
    reliable: bool = option(
        True, unit="-", doc="QoS reliability of the inputs and outputs (false: best effort)"
    )
    depth: int = option(10, unit="messages", doc="QoS history depth (keep last)", **_POSITIVE)
    publish_rate: float = option(
        0.0,
        unit="Hz",
        doc="most Odometry/TF per second (message time); 0: one per odometry step",
        **_NONNEG,
    )
    timeout: float = option(
        1.0,
        unit="s",
        doc="a sensor silent this long (message time) raises a timeout finding",
        **_POSITIVE,
    )
    timeouts: dict[str, float] | None = option(
        None, unit="s", doc="stream -> its own timeout (overrides timeout)"
    )
    diagnostics_period: float = option(
        1.0, unit="s", doc="diagnostics every this many seconds of message time", **_POSITIVE
    )
