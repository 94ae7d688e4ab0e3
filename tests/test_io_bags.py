"""ROS 2 bags (sqlite3 and MCAP storage) written here with rosbags and read back."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from odofuse.errors import InputError  # noqa: E402
from odofuse.io.bags import odometry_increments, read_bag  # noqa: E402
from odofuse.io.loader import load_log  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types


def header(t, frame="base_link"):
    sec = int(math.floor(t))
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9))),
        frame_id=frame,
    )


def quat(yaw):
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def odom_msg(t, x, y, yaw):
    g = T
    pose = g["geometry_msgs/msg/PoseWithCovariance"](
        pose=g["geometry_msgs/msg/Pose"](
            position=g["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quat(yaw)
        ),
        covariance=np.zeros(36),
    )
    twist = g["geometry_msgs/msg/TwistWithCovariance"](
        twist=g["geometry_msgs/msg/Twist"](
            linear=g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            angular=g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
        ),
        covariance=np.zeros(36),
    )
    return g["nav_msgs/msg/Odometry"](
        header=header(t, "odom"), child_frame_id="base_link", pose=pose, twist=twist
    )


def imu_msg(t, wz):
    v3 = T["geometry_msgs/msg/Vector3"]
    return T["sensor_msgs/msg/Imu"](
        header=header(t),
        orientation=quat(0.0),
        orientation_covariance=np.zeros(9),
        angular_velocity=v3(x=0.0, y=0.0, z=wz),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=v3(x=0.0, y=0.0, z=0.0),
        linear_acceleration_covariance=np.zeros(9),
    )


def fix_msg(t, lat, lon, var, status=0):
    st = T["sensor_msgs/msg/NavSatStatus"](status=status, service=1)
    cov = np.zeros(9)
    cov[0] = cov[4] = var
    return T["sensor_msgs/msg/NavSatFix"](
        header=header(t, "gps"),
        status=st,
        latitude=lat,
        longitude=lon,
        altitude=0.0,
        position_covariance=cov,
        position_covariance_type=2 if var else 0,
    )


def joint_msg(t, names, pos):
    return T["sensor_msgs/msg/JointState"](
        header=header(t),
        name=list(names),
        position=np.asarray(pos, dtype=float),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )


POSES = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0 + math.cos(0.0), 0.1, 0.3), (2.5, 1.0, -3.0)]


def write_bag(path, storage=StoragePlugin.SQLITE3, extra_joint_topic=False):
    with Writer(path, version=9, storage_plugin=storage) as w:
        conns = {
            "/joint_states": w.add_connection(
                "/joint_states", "sensor_msgs/msg/JointState", typestore=TS
            ),
            "/odom": w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=TS),
            "/imu": w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=TS),
            "/fix": w.add_connection("/fix", "sensor_msgs/msg/NavSatFix", typestore=TS),
        }
        if extra_joint_topic:
            conns["/other_joints"] = w.add_connection(
                "/other_joints", "sensor_msgs/msg/JointState", typestore=TS
            )

        def put(topic, t, msg, msgtype):
            w.write(conns[topic], int(t * 1e9), TS.serialize_cdr(msg, msgtype))

        for k in range(4):
            t = 10.0 + 0.5 * k
            # joint order changes in the last message: the reader maps by name
            names, pos = (
                (("left", "right"), (0.1 * k, 0.2 * k))
                if k < 3
                else (("right", "left"), (0.2 * k, 0.1 * k))
            )
            put("/joint_states", t, joint_msg(t, names, pos), "sensor_msgs/msg/JointState")
            put("/odom", t, odom_msg(t, *POSES[k]), "nav_msgs/msg/Odometry")
            put("/imu", t, imu_msg(t, 0.01 * k), "sensor_msgs/msg/Imu")
            put(
                "/fix",
                t,
                fix_msg(t, 45.0 + 1e-5 * k, 9.0, 4.0, status=-1 if k == 2 else 0),
                "sensor_msgs/msg/NavSatFix",
            )
            if extra_joint_topic:
                put(
                    "/other_joints", t, joint_msg(t, ("arm",), (1.0,)), "sensor_msgs/msg/JointState"
                )
    return path


def check(log):
    w = log.streams["wheels"]
    assert w.columns == ("left", "right")
    np.testing.assert_allclose(w.t, [10.0, 10.5, 11.0, 11.5])
    np.testing.assert_allclose(w["left"], [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(w["right"], [0.0, 0.2, 0.4, 0.6])
    o = log.streams["odometry"]
    np.testing.assert_allclose(o.t, [10.5, 11.0, 11.5])
    ti, inc = odometry_increments([0, 1, 2, 3], POSES)
    np.testing.assert_allclose(o.values, inc, atol=1e-12)
    np.testing.assert_allclose(log.streams["gyro"]["wz"], [0.0, 0.01, 0.02, 0.03])
    g = log.streams["gps"]
    assert g.columns == ("lat", "lon", "sigma")
    np.testing.assert_allclose(g.t, [10.0, 10.5, 11.5])
    np.testing.assert_allclose(g["sigma"], 2.0)
    assert log.repairs == {"gps.no_fix_dropped": 1}


def test_increments_reference():
    # 1 m forward while facing north and turning 0.1; 0.5 m backwards; a turn through +-pi
    t, inc = odometry_increments([0, 1], [(1.0, 2.0, math.pi / 2), (1.0, 3.0, math.pi / 2 + 0.1)])
    np.testing.assert_allclose(inc, [[1.0, 0.1]], atol=1e-12)
    _, inc = odometry_increments([0, 1], [(0.0, 0.0, 0.0), (-0.5, 0.0, 0.0)])
    np.testing.assert_allclose(inc, [[-0.5, 0.0]])
    _, inc = odometry_increments([0, 1], [(0.0, 0.0, 3.1), (0.0, 0.0, -3.1)])
    assert inc[0, 1] == pytest.approx(2 * math.pi - 6.2)  # wrapped through +-pi


def test_sqlite_bag(tmp_path):
    path = write_bag(tmp_path / "run_db3")
    check(read_bag(path))
    check(load_log(path))  # the loader recognises a bag folder


def test_mcap_bag(tmp_path):
    path = write_bag(tmp_path / "run_mcap", StoragePlugin.MCAP)
    assert list(path.glob("*.mcap"))
    check(load_log(path))
    check(load_log(next(path.glob("*.mcap"))))  # the .mcap file inside the bag folder


def test_topic_mapping(tmp_path):
    path = write_bag(tmp_path / "two", extra_joint_topic=True)
    with pytest.raises(InputError, match="several sensor_msgs/msg/JointState topics"):
        read_bag(path)
    check(read_bag(path, topics={"wheels": "/joint_states"}))
    log = read_bag(path, topics={"wheels": "/other_joints"})
    assert log.streams["wheels"].columns == ("arm",)
    with pytest.raises(InputError, match="not in the bag"):
        read_bag(path, topics={"wheels": "/nope"})
    with pytest.raises(InputError, match="needs sensor_msgs/msg/JointState"):
        read_bag(path, topics={"wheels": "/imu"})


def test_unreadable_bag(tmp_path):
    bad = tmp_path / "broken"
    bad.mkdir()
    (bad / "metadata.yaml").write_text("not: a bag\n")
    with pytest.raises(InputError, match="cannot read bag"):
        load_log(bad)
