"""The estimate as a ROS 2 user replays it: ``trajectory.mcap`` (nav_msgs/Odometry + TF).

One MCAP file (rosbag2 MCAP storage written with ``rosbags``; its ``Writer`` writes MCAP since
rosbags 0.10.9, the project pins ``rosbags>=0.11.1,<0.12``), readable by rosbags, Foxglove and
``ros2 bag play trajectory.mcap`` (Humble: add ``-s mcap``). Per pose ``k`` of the estimate,
stamped ``t_k``:

* ``/odometry/filtered`` (``nav_msgs/msg/Odometry``): ``header.frame_id`` the map frame,
  ``child_frame_id`` the base frame, the pose ``[x, y, theta]`` (z = 0, yaw quaternion) and
  its covariance. ``nav_msgs`` defines the pose covariance in ``header.frame_id`` over
  ``(x, y, z, roll, pitch, yaw)``, row-major 6x6: odofuse's world-frame ``[x, y, theta]``
  covariance is that frame's, so it is placed at rows/columns 0, 1, 5 without rotation; z,
  roll and pitch are not estimated (planar, like robot_localization's ``two_d_mode``) and their
  rows are 0. The twist is not estimated: zero with an all-zero (unknown) covariance.
* ``/tf`` (``tf2_msgs/msg/TFMessage``), REP-105: ``map -> odom`` and ``odom -> base_link``.
  ``odom -> base_link`` is the run's dead reckoning (continuous, drifting), ``map -> odom`` the
  correction ``T_map_base * T_odom_base^-1`` so that composing the two gives the estimate.

The file is written into a temporary bag folder next to the target and renamed into place, so
a failing run leaves no half-written ``trajectory.mcap``.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from odofuse import se2
from odofuse.trajectory import Trajectory

DEFAULT_FRAMES = {"map_frame": "map", "odom_frame": "odom", "base_frame": "base_link"}
DEFAULT_TOPIC = "/odometry/filtered"
OPTION_KEYS = ("mcap", "topic", *DEFAULT_FRAMES)
#: (index in the 6x6 ROS pose covariance) of x, y, yaw
_ROS_IDX = (0, 1, 5)


def ros_pose_covariance(P) -> np.ndarray:
    """Planar ``[x, y, theta]`` covariance ``(3, 3)`` -> ROS pose covariance ``(36,)``."""
    C = np.zeros((6, 6))
    C[np.ix_(_ROS_IDX, _ROS_IDX)] = np.asarray(P, dtype=float)
    return C.reshape(-1)


def mcap_options(config, log) -> dict | None:
    """The MCAP writer's keyword arguments for a run, or None when no MCAP is wanted.

    ``options: {output: {mcap, topic, map_frame, odom_frame, base_frame}}`` in the config;
    ``mcap`` defaults to true when the log is a ROS bag. Frame names default to the bag's
    (Odometry ``header.frame_id`` / ``child_frame_id``), else ``map``, ``odom``, ``base_link``.

    Raises
    ------
    ConfigError
        An unknown key in ``options.output``.
    """
    opts = config.estimator_options("output")
    ros = getattr(log, "ros", {}) or {}
    if not (opts.mcap if opts.mcap is not None else "base_frame" in ros):  # read_bag sets it
        return None
    frames = dict(DEFAULT_FRAMES)
    if ros.get("odom_frame"):
        frames["odom_frame"] = ros["odom_frame"]
    if ros.get("base_frame"):
        frames["base_frame"] = ros["base_frame"]
    frames.update({k: getattr(opts, k) for k in DEFAULT_FRAMES if getattr(opts, k) is not None})
    return {"topic": opts.topic, **frames}


def write_trajectory_mcap(
    path,
    traj: Trajectory,
    odom_poses=None,
    *,
    topic: str = DEFAULT_TOPIC,
    map_frame: str = "map",
    odom_frame: str = "odom",
    base_frame: str = "base_link",
) -> Path:
    """Write ``trajectory.mcap`` (see the module docstring) atomically.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.
    traj : Trajectory
        The estimate, map frame; covariances (world frame) optional (zero when absent).
    odom_poses : array_like (N, 3), optional
        Base pose in the odom frame at ``traj.t`` (dead reckoning); ``None``: the odom frame is
        the map frame (identity ``map -> odom``).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    poses = np.asarray(traj.poses, dtype=float)
    odom = poses if odom_poses is None else np.asarray(odom_poses, dtype=float)
    covs = traj.covariances if traj.covariances is not None else np.zeros((len(traj), 3, 3))
    v3 = T["geometry_msgs/msg/Vector3"]

    def header(ns, frame):
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id=frame,
        )

    def quat(yaw):
        return T["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw)
        )

    def transform(ns, parent, child, p):
        return T["geometry_msgs/msg/TransformStamped"](
            header=header(ns, parent),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=v3(x=float(p[0]), y=float(p[1]), z=0.0), rotation=quat(float(p[2]))
            ),
        )

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.stem}.", dir=path.parent))
    bag = tmp / "bag"
    odo_type, tf_type = "nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage"
    try:
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            c_odo = w.add_connection(topic, odo_type, typestore=ts)
            c_tf = w.add_connection("/tf", tf_type, typestore=ts)
            for k in range(len(traj)):
                ns = int(round(float(traj.t[k]) * 1e9))
                p = poses[k]
                msg = T[odo_type](
                    header=header(ns, map_frame),
                    child_frame_id=base_frame,
                    pose=T["geometry_msgs/msg/PoseWithCovariance"](
                        pose=T["geometry_msgs/msg/Pose"](
                            position=T["geometry_msgs/msg/Point"](
                                x=float(p[0]), y=float(p[1]), z=0.0
                            ),
                            orientation=quat(float(p[2])),
                        ),
                        covariance=ros_pose_covariance(covs[k]),
                    ),
                    twist=T["geometry_msgs/msg/TwistWithCovariance"](
                        twist=T["geometry_msgs/msg/Twist"](
                            linear=v3(x=0.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0)
                        ),
                        covariance=np.zeros(36),
                    ),
                )
                w.write(c_odo, ns, ts.serialize_cdr(msg, odo_type))
                map_odom = se2.compose(p, se2.inverse(odom[k]))
                tf = T[tf_type](
                    transforms=[
                        transform(ns, map_frame, odom_frame, map_odom),
                        transform(ns, odom_frame, base_frame, odom[k]),
                    ]
                )
                w.write(c_tf, ns, ts.serialize_cdr(tf, tf_type))
        (mcap,) = bag.glob("*.mcap")
        os.replace(mcap, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path
