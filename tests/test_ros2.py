"""The ROS 2 user (issue 14): a simulated robot recorded as a bag, run with a ten-line config.

Bags are written here with rosbags (``rosbag_sim``: MCAP and sqlite3 storage): JointState
50 Hz, two IMUs (100 Hz biased gyro; 50 Hz gyro + AHRS yaw mounted at 90 deg), NavSatFix 1 Hz
with two outliers, Odometry 50 Hz, /tf_static.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import subprocess

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbag_sim import (  # noqa: E402
    CONFIG,
    GPS_LEVER,
    GYRO_BIAS,
    GYRO_SIGMA,
    IMU2_YAW_SIGMA,
    T0,
    simulate_robot,
    write_robot_bag,
)

from odofuse import cli, rundir, se2  # noqa: E402
from odofuse.config import load_config  # noqa: E402
from odofuse.errors import InputError  # noqa: E402
from odofuse.io import ros_msgs  # noqa: E402
from odofuse.io.bags import read_bag  # noqa: E402
from odofuse.io.loader import load_log_for  # noqa: E402
from odofuse.io.log import Stream  # noqa: E402
from odofuse.log_defaults import apply_log_defaults  # noqa: E402
from odofuse.outputs import read_trajectory_csv  # noqa: E402
from odofuse.trajectory import (
    Trajectory,  # noqa: E402
    interpolate_poses,  # noqa: E402
)

TOPICS = {"gyro": ["/imu/data", "/imu2/data"]}
JOINTS = {"left": "left_wheel_joint", "right": "right_wheel_joint"}


@pytest.fixture(scope="module")
def robot():
    return simulate_robot()


@pytest.fixture(scope="module")
def bags(robot, tmp_path_factory):
    base = tmp_path_factory.mktemp("bags")
    return {s: write_robot_bag(base / f"run_{s}", robot, s) for s in ("mcap", "sqlite3")}


def rmse(traj: Trajectory, robot) -> float:
    truth = interpolate_poses(Trajectory(robot.t + T0, robot.truth), traj.t)
    return float(np.sqrt(np.mean(np.sum((traj.poses[:, :2] - truth[:, :2]) ** 2, axis=1))))


def test_bag_streams_both_storages(bags, robot):
    logs = {s: read_bag(p, topics=TOPICS, joints=JOINTS) for s, p in bags.items()}
    log = logs["mcap"]
    assert set(log.streams) == {"wheels", "odometry", "gyro", "gyro_2", "compass_2", "gps"}
    for name, s in log.streams.items():  # both storages give the same log
        other = logs["sqlite3"].streams[name]
        assert s.columns == other.columns
        np.testing.assert_array_equal(s.values, other.values)
    w = log.streams["wheels"]
    assert w.columns == ("left", "right") and len(w) == len(robot.t[::2])
    np.testing.assert_allclose(w.values, robot.wheels[::2])
    np.testing.assert_allclose(w.t, T0 + robot.t[::2], atol=1e-6)
    g = log.streams["gyro"]
    assert g.columns == ("wz", "sigma") and len(g) == len(robot.t) - 1
    np.testing.assert_allclose(g["sigma"], GYRO_SIGMA)
    assert "compass" not in log.streams  # /imu/data: orientation_covariance[0] == -1
    # the AHRS yaw in imu2_link, with the 90 deg mount removed via /tf_static
    c = log.streams["compass_2"]
    err = se2.wrap(
        c["heading"] - interpolate_poses(Trajectory(robot.t + T0, robot.truth), c.t)[:, 2]
    )
    assert abs(np.mean(err)) < 4 * IMU2_YAW_SIGMA / math.sqrt(len(c))
    np.testing.assert_allclose(c["sigma"], IMU2_YAW_SIGMA)
    assert log.streams["gps"].columns == ("lat", "lon", "sigma")
    o = log.streams["odometry"]
    dt = np.diff(o.t).mean()
    np.testing.assert_allclose(o["var_ds"], 1e-4 * dt**2, rtol=1e-3)
    np.testing.assert_allclose(o["var_dtheta"], 1e-3 * dt**2, rtol=1e-3)
    ros = log.ros
    assert (ros["base_frame"], ros["odom_frame"]) == ("base_link", "odom")
    np.testing.assert_allclose(ros["mounts"]["gps"], [*GPS_LEVER, 0.0])
    assert ros["frames"]["gyro_2"] == "imu2_link"


def _same_log(a, b):
    assert list(a.streams) == list(b.streams) and a.repairs == b.repairs and a.ros == b.ros
    for name, s in a.streams.items():
        o = b.streams[name]
        assert s.columns == o.columns
        np.testing.assert_array_equal(s.t, o.t)
        np.testing.assert_array_equal(s.values, o.values)


def test_columnar_decoding_equals_message_by_message(bags, monkeypatch):
    from odofuse.io import cdr

    decoded = []

    def counted(raws, msgtype, *args):
        cols = decode(raws, msgtype, *args)
        decoded.append((msgtype, cols is not None))
        return cols

    decode = cdr.decode
    monkeypatch.setattr(cdr, "decode", counted)
    for path in bags.values():
        decoded.clear()
        _same_log(read_bag(path, TOPICS, JOINTS), read_bag(path, TOPICS, JOINTS, columnar=False))
        # every stream of the simulated robot took the columnar path
        assert len(decoded) == 5 and all(ok for _, ok in decoded), decoded


def test_messages_of_several_layouts_are_decoded_one_by_one(tmp_path, bags):
    """A topic whose joint order, frame or sequence lengths change between messages: each
    message is matched by name as before (the columnar path applies to one layout only)."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with AnyReader([bags["mcap"]], default_typestore=ts) as r:
        keep = ("/tf_static", "/joint_states", "/imu/data")
        conns = [c for c in r.connections if c.topic in keep]
        items = [(c, ns, r.deserialize(d, c.msgtype)) for c, ns, d in r.messages(conns)][:400]
    with Writer(tmp_path / "mixed", version=9) as w:
        out = {c.topic: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in conns}
        for k, (c, ns, msg) in enumerate(items):
            if c.topic == "/joint_states" and k % 3 == 0:  # the same joints, swapped
                msg.name = msg.name[::-1]
                msg.position = msg.position[::-1].copy()
            w.write(out[c.topic], ns, ts.serialize_cdr(msg, c.msgtype))
    log = read_bag(tmp_path / "mixed", joints=JOINTS)
    _same_log(log, read_bag(tmp_path / "mixed", joints=JOINTS, columnar=False))
    full = read_bag(bags["mcap"], TOPICS, JOINTS).streams["wheels"]
    w = log.streams["wheels"]
    np.testing.assert_array_equal(w.values, full.values[: len(w)])
    # one message in another frame of the same length: the frame check still sees it
    with Writer(tmp_path / "frames", version=9) as w:
        out = {c.topic: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in conns}
        for k, (c, ns, msg) in enumerate(items):
            if c.topic == "/imu/data" and k == 200:
                msg.header.frame_id = "imu_lynx"
            w.write(out[c.topic], ns, ts.serialize_cdr(msg, c.msgtype))
    with pytest.raises(InputError, match=r"messages in several frames \(imu_link, imu_lynx"):
        read_bag(tmp_path / "frames", joints=JOINTS)


def test_joint_velocity_integrated(tmp_path, robot):
    short = dataclasses.replace(robot, t=robot.t[:2001], truth=robot.truth[:2001])
    short = dataclasses.replace(short, wheels=robot.wheels[:2001], gyro=robot.gyro[:2001])
    log = read_bag(
        write_robot_bag(tmp_path / "vel", short, "mcap", velocity_only=True), TOPICS, JOINTS
    )
    w = log.streams["wheels"]
    assert log.repairs["wheels.velocity_integrated"] == len(w)
    # trapezoidal integration of central-difference speeds: exact on constant speed, off by
    # about a step's change where the speed jumps (corners), and no drift after 20 s
    np.testing.assert_allclose(w.values, robot.wheels[:2001:2], atol=2e-2)
    np.testing.assert_allclose(w.values[-1], robot.wheels[2000], atol=2e-3)


def test_unknown_mapping_and_frame(tmp_path, robot, bags):
    with pytest.raises(InputError, match=r"joint 'left_wheel' \(log.joints.left\) is not in"):
        read_bag(bags["mcap"], TOPICS, {"left": "left_wheel", "right": "right_wheel_joint"})
    with pytest.raises(InputError, match="several sensor_msgs/msg/Imu topics"):
        read_bag(bags["mcap"], None, JOINTS)
    # a message frame that /tf_static does not know
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    from rosbags.highlevel import AnyReader

    with AnyReader([bags["mcap"]], default_typestore=ts) as r:
        conns = [c for c in r.connections if c.topic in ("/tf_static", "/imu/data")]
        items = [(c, ns, r.deserialize(d, c.msgtype)) for c, ns, d in r.messages(conns)][:20]
    with Writer(tmp_path / "badframe", version=9) as w:
        out = {c.topic: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in conns}
        for c, ns, msg in items:
            if c.topic == "/imu/data":
                msg.header.frame_id = "camera_link"
            w.write(out[c.topic], ns, ts.serialize_cdr(msg, c.msgtype))
    with pytest.raises(InputError, match="frame 'camera_link' is not connected to 'base_link'"):
        read_bag(tmp_path / "badframe")


def test_covariance_conventions():
    from rosbags.typesys import Stores, get_typestore

    T = get_typestore(Stores.ROS2_HUMBLE).types
    v3, q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]

    def imu(oc, avc, quat=(0.0, 0.0, 0.0, 1.0)):
        return T["sensor_msgs/msg/Imu"](
            header=T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id=""
            ),
            orientation=q(x=quat[0], y=quat[1], z=quat[2], w=quat[3]),
            orientation_covariance=np.asarray(oc, dtype=float),
            angular_velocity=v3(x=0.0, y=0.0, z=0.1),
            angular_velocity_covariance=np.asarray(avc, dtype=float),
            linear_acceleration=v3(x=0.0, y=0.0, z=0.0),
            linear_acceleration_covariance=np.zeros(9),
        )

    known = np.diag([1e-4, 1e-4, 4e-4]).reshape(-1)
    minus = np.r_[-1.0, np.zeros(8)]
    zero = np.zeros(9)

    def imu_columns(msgs, yaw_offset=0.0):
        return ros_msgs.imu_columns(ros_msgs.columns(msgs, ros_msgs.IMU), yaw_offset)

    (cols, vals), compass = imu_columns([imu(minus, known)])
    assert cols == ("wz", "sigma") and vals[0, 1] == pytest.approx(0.02) and compass is None
    (cols, _), compass = imu_columns([imu(zero, zero)])  # unknown: no noise column
    assert cols == ("wz",) and compass is None
    (cols, _), _ = imu_columns([imu(known, minus)])  # rate "not provided"
    assert cols == ("wz",)
    yaw = 0.3
    quat = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    _, (ccols, cvals, keep) = imu_columns(
        [imu(known, known, quat), imu(minus, known, quat)], yaw_offset=0.1
    )
    assert ccols == ("heading", "sigma") and keep.tolist() == [True, False]
    np.testing.assert_allclose(cvals, [[0.2, 0.02]])


def test_log_defaults_precedence(bags):
    log = read_bag(bags["mcap"], TOPICS, JOINTS)
    cfg = load_config_text(bags["mcap"], "ekf")
    c2, l2 = apply_log_defaults(cfg, log)
    assert list(c2.sensors["gps"].lever_arm) == list(GPS_LEVER)  # from /tf_static
    assert c2.sensors["compass_2"].model == "compass"
    assert "sigma" in l2.streams["gyro"].columns  # message covariance used
    assert "gps.datum_first_fix" not in l2.repairs  # the config gives the datum
    # a sigma in the config overrides the message covariance; no datum: first fix, counted
    cfg = dataclasses.replace(cfg, sensors={"gyro": {"sigma": 0.05}, "gps": {"lever_arm": [0, 0]}})
    c3, l3 = apply_log_defaults(cfg, log)
    assert l3.streams["gyro"].columns == ("wz",)
    assert list(c3.sensors["gps"].lever_arm) == [0, 0]
    assert l3.repairs["gps.datum_first_fix"] == 1
    assert list(c3.sensors["gps"].datum) == [
        float(log.streams["gps"]["lat"][0]),
        float(log.streams["gps"]["lon"][0]),
    ]
    assert l3.ros["defaults"]["sensors.gps.datum"] == list(c3.sensors["gps"].datum)
    # a bag's GPS gets Huber in the graph estimators unless the config names a loss
    assert c2.sensors["gps"].robust == ("huber", 1.345)
    assert c2.estimator_options("isam2").robust["gps"] == ("huber", 1.345)
    cfg = dataclasses.replace(cfg, sensors={"gps": {"datum": [45.0, 9.0], "robust": "none"}})
    assert apply_log_defaults(cfg, log)[0].sensors["gps"].robust == ("none", 0.0)


def test_log_defaults_applied_twice_change_nothing(bags):
    # benchmarks/bench_status.py applied them twice to its second opinion's config: a CSV
    # log's empty ``ros`` had become ``{"message_noise": {}, "defaults": {}}`` after one pass,
    # so the second took it for a bag and gave its GPS Huber's loss (session 32)
    from odofuse.teaching import trust_scenarios as ts

    csv_log, csv_cfg = ts.simulated("gps_outage", laps=1)
    assert "gps" in csv_cfg.sensors and not csv_log.ros
    for cfg, log in (
        (load_config_text(bags["mcap"], "ekf"), read_bag(bags["mcap"], TOPICS, JOINTS)),
        (csv_cfg, csv_log),
    ):
        c1, l1 = apply_log_defaults(cfg, log)
        c2, l2 = apply_log_defaults(c1, l1)
        assert c2 == c1 and l2.ros == l1.ros and l2.repairs == l1.repairs
        assert c1.sensors["gps"].robust == (("huber", 1.345) if log.ros else None)


def test_increments_take_odometry_covariance(bags):
    log = read_bag(bags["mcap"], {"gyro": "/imu/data"}, JOINTS)
    cfg = dataclasses.replace(
        load_config_text(bags["mcap"], "ekf"), robot={"drive": "increments"}, sensors={}
    )
    c2, _ = apply_log_defaults(cfg, log)
    o = log.streams["odometry"]
    assert list(c2.motion.var_floor) == [
        float(np.median(o["var_ds"])),
        float(np.median(o["var_dtheta"])),
    ]
    cfg = dataclasses.replace(cfg, motion={"k": [1e-3, 1e-3]})
    assert apply_log_defaults(cfg, log)[0].motion.var_floor == 0.0  # the config's k wins


def load_config_text(bag, estimator):
    from odofuse.config import config_from_dict, parse_yaml

    return config_from_dict(parse_yaml(CONFIG.format(bag=bag, estimator=estimator), "cfg"), "cfg")


@pytest.fixture(scope="module")
def ekf_run(bags, tmp_path_factory):
    """``odofuse run`` with the ten-line config on the MCAP bag."""
    d = tmp_path_factory.mktemp("ekf")
    cfg = d / "run.yaml"
    cfg.write_text(CONFIG.format(bag=bags["mcap"], estimator="ekf"))
    assert len(cfg.read_text().splitlines()) == 10
    assert cli.main(["run", str(cfg), "-o", str(d / "out")]) == 0
    return d / "out", load_config(cfg)


def test_ekf_on_the_bag(ekf_run, robot):
    out, _ = ekf_run
    traj = read_trajectory_csv(out / "trajectory.csv")
    err = rmse(traj, robot)
    print(f"EKF RMSE on the simulated bag: {err:.3f} m")
    assert err < 0.40
    m = json.loads((out / "metrics.json").read_text())
    assert m["sensors"]["gps"]["rejected"] >= 2  # the two outliers
    assert abs(m["extra"]["calibration"]["gyro_bias"]["value"] - GYRO_BIAS) < 3e-3
    assert m["log_defaults"]["sensors.gps.lever_arm"] == list(GPS_LEVER)
    assert {"ekf.tum", "trajectory.tum", "trajectory.mcap"} <= {p.name for p in out.iterdir()}


def test_mcap_read_back(ekf_run):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from odofuse.rundir import dead_reckoning_at

    out, cfg = ekf_run
    traj = read_trajectory_csv(out / "trajectory.csv")
    with AnyReader(
        [out / "trajectory.mcap"], default_typestore=get_typestore(Stores.ROS2_HUMBLE)
    ) as r:
        topics = {c.topic: c.msgtype for c in r.connections}
        assert topics == {
            "/odometry/filtered": "nav_msgs/msg/Odometry",
            "/tf": "tf2_msgs/msg/TFMessage",
        }
        odo, tf = [], []
        for c, _, data in r.messages():
            (odo if c.topic == "/odometry/filtered" else tf).append(r.deserialize(data, c.msgtype))
    assert len(odo) == len(tf) == len(traj)  # one Odometry message per pose
    t = np.array([ros_msgs.stamp(m, 0) for m in odo])
    np.testing.assert_allclose(t, traj.t, atol=1e-6)
    pose = np.array(
        [
            [m.pose.pose.position.x, m.pose.pose.position.y, ros_msgs.yaw(m.pose.pose.orientation)]
            for m in odo
        ]
    )
    np.testing.assert_allclose(pose[:, :2], traj.poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(se2.wrap(pose[:, 2] - traj.poses[:, 2]), 0.0, atol=1e-9)
    cov = np.array([np.asarray(m.pose.covariance).reshape(6, 6) for m in odo])
    idx = [0, 1, 5]  # x, y, yaw of (x, y, z, roll, pitch, yaw): the header (map) frame's
    np.testing.assert_allclose(cov[:, idx][:, :, idx], traj.covariances, rtol=1e-12, atol=1e-18)
    assert not np.any(cov[:, 2:5, :]) and not np.any(cov[:, :, 2:5])
    assert {(m.header.frame_id, m.child_frame_id) for m in odo} == {("map", "base_link")}
    # REP-105: map -> odom -> base_link, composing to the estimate; odom -> base_link is the
    # dead reckoning
    chain = {(tr.header.frame_id, tr.child_frame_id) for m in tf for tr in m.transforms}
    assert chain == {("map", "odom"), ("odom", "base_link")}

    def planar(tr):
        return np.array(
            [
                tr.transform.translation.x,
                tr.transform.translation.y,
                ros_msgs.yaw(tr.transform.rotation),
            ]
        )

    map_odom = np.array([planar(m.transforms[0]) for m in tf])
    odom_base = np.array([planar(m.transforms[1]) for m in tf])
    composed = se2.compose(map_odom, odom_base)
    np.testing.assert_allclose(composed[:, :2], traj.poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(se2.wrap(composed[:, 2] - traj.poses[:, 2]), 0.0, atol=1e-9)
    cfg, log = apply_log_defaults(cfg, load_log_for(cfg))
    dr = dead_reckoning_at(cfg, log, traj.t)
    np.testing.assert_allclose(odom_base[:, :2], dr[:, :2], atol=1e-9)


def test_mcap_on_request_and_frames_from_the_config(bags, tmp_path):
    """trajectory.mcap: by default for a bag, on request otherwise; frames config > bag."""
    from types import SimpleNamespace

    from odofuse.config import config_from_dict, parse_yaml
    from odofuse.outputs_ros import mcap_options

    def cfg(output):
        text = CONFIG.format(bag=bags["mcap"], estimator="ekf")
        return config_from_dict(parse_yaml(text + f"options: {{output: {output}}}\n", "cfg"), "cfg")

    bag_log = read_bag(bags["mcap"], TOPICS, JOINTS)
    csv_log = SimpleNamespace(ros={})
    frames = {"map_frame": "map", "odom_frame": "odom", "base_frame": "base_link"}
    assert mcap_options(cfg("{}"), bag_log) == {"topic": "/odometry/filtered", **frames}
    assert mcap_options(cfg("{mcap: false}"), bag_log) is None
    assert mcap_options(cfg("{}"), csv_log) is None
    assert mcap_options(cfg("{mcap: true}"), csv_log) == {"topic": "/odometry/filtered", **frames}
    got = mcap_options(cfg("{topic: /est, map_frame: world, base_frame: robot}"), bag_log)
    assert got == {
        "topic": "/est",
        "map_frame": "world",
        "odom_frame": "odom",
        "base_frame": "robot",
    }
    # a CSV-style log (Plaza1) asked for the MCAP: one Odometry per pose, the config's frames
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = tmp_path / "dr.yaml"
    text = cli.default_config_path("dead_reckoning").read_text()
    # the MCAP is what is checked here, not the second opinion (a smoother run of Plaza1)
    opts = "options: {output: {mcap: true, map_frame: world}, cross_check: {smoother: off}}"
    path.write_text(text + opts + "\n")
    config = load_config(path)
    m = rundir.run_one(config, load_log_for(config), tmp_path / "out")
    with AnyReader(
        [tmp_path / "out" / "trajectory.mcap"], default_typestore=get_typestore(Stores.ROS2_HUMBLE)
    ) as r:
        conns = [c for c in r.connections if c.topic == "/odometry/filtered"]
        odo = [r.deserialize(d, c.msgtype) for c, _, d in r.messages(conns)]
    assert len(odo) == m["poses"]
    assert {(o.header.frame_id, o.child_frame_id) for o in odo} == {("world", "base_link")}


@pytest.mark.parametrize("compass", [True, False])
@pytest.mark.parametrize("estimator", ["isam2", "fixed_lag"])
def test_incremental_smoothers_on_the_bag(bags, robot, tmp_path, estimator, compass):
    """Issue 14's judged bound: iSAM2 within 0.40 m of the simulated truth, 100 Hz gyro.

    The ten-line config, and the same without ``compass_2``. The 50 Hz AHRS yaw attaches to
    the keyframes (before: 7,834 keyframes, iSAM2 128 s, fixed-lag 211 s). Measured with
    compass_2: iSAM2 0.052 m, fixed-lag 0.049 m; without: iSAM2 0.067 m (position NEES mean
    1.3 of 2), fixed-lag 0.105 m; 159 keyframes either way. Without the bag's default GPS
    robust loss the two 25 m outliers shift the rigid trajectory ~0.3 m east (0.376 m).
    """
    cfg = tmp_path / "run.yaml"
    text = CONFIG.format(bag=bags["mcap"], estimator=estimator)
    cfg.write_text(text if compass else text.replace("  compass_2: {}\n", ""))
    assert cli.main(["run", str(cfg), "-o", str(tmp_path / "out")]) == 0
    traj = read_trajectory_csv(tmp_path / "out" / "trajectory.csv")
    err = rmse(traj, robot)
    print(f"{estimator} RMSE on the simulated bag: {err:.3f} m")
    assert err < 0.20  # judged: 0.40 m
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["status"] == "ok" and m["extra"]["keyframes"] < 200  # the gyro pre-integrated
    assert m["log_defaults"]["sensors.gps.robust"] == ["huber", 1.345]
    truth = interpolate_poses(Trajectory(robot.t + T0, robot.truth), traj.t)
    e = traj.poses[:, :2] - truth[:, :2]
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(traj.covariances[:, :2, :2]), e)
    assert np.mean(nees) < 4.0  # 2 position dof: the covariance is not overconfident


def test_high_rate_compass_follows_the_keyframe_policy(tmp_path, robot):
    """The 50 Hz AHRS yaw (compass_2) attaches to the policy's keyframes (gaps item 1).

    40 s of the bag: keyframes are the 1 s grid (GPS at the same whole seconds) and the gyro
    stream's first accepted sample (0.01 s), 42 in all, with or without compass_2; every
    compass reading is used, one averaged factor per keyframe (but the first). Before: one
    keyframe per reading (2,000 in 40 s; 7,834 on the whole bag, iSAM2 128 s, fixed-lag
    211 s).
    """
    from odofuse.estimators import run_estimator

    n = 4001
    short = dataclasses.replace(
        robot, t=robot.t[:n], truth=robot.truth[:n], wheels=robot.wheels[:n], gyro=robot.gyro[:n]
    )
    bag = write_robot_bag(tmp_path / "short", short, "mcap")
    errs = {}
    for estimator in ("isam2", "fixed_lag"):
        for compass in (True, False):
            cfg = load_config_text(bag, estimator)
            if not compass:
                cfg = dataclasses.replace(
                    cfg, sensors={k: v for k, v in cfg.sensors.items() if k != "compass_2"}
                )
            cfg, log = apply_log_defaults(cfg, load_log_for(cfg))
            res = run_estimator(estimator, log, cfg)
            assert res.extra["keyframes"] == 42, (estimator, compass)
            errs[estimator, compass] = rmse(res.trajectory, short)
            if compass:
                c = log.streams["compass_2"]
                assert len(c) == 2000 and res.used["compass_2"] == len(c)
                summary = res.extra["residuals"]["compass_2"]
                # one averaged reading per keyframe but the first (0 s): the first reading is
                # at 0.02 s, nearer the 0.01 s keyframe
                assert summary["factors"] == 41
                # the averaged headings' stated variance holds: no large residuals
                assert summary["beyond_999"] <= 0.05
    print("RMSE on 40 s of the bag (m):", {k: round(v, 3) for k, v in errs.items()})
    for estimator in ("isam2", "fixed_lag"):
        assert errs[estimator, True] < 0.20  # judged: 0.40 m
        # the compass helps (measured 40 s: see the printout)
        assert errs[estimator, True] < errs[estimator, False]


@pytest.mark.slow
def test_smoother_on_the_bag(bags, robot, tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(CONFIG.format(bag=bags["mcap"], estimator="smoother"))
    assert cli.main(["run", str(cfg), "-o", str(tmp_path / "out")]) == 0
    err = rmse(read_trajectory_csv(tmp_path / "out" / "trajectory.csv"), robot)
    print(f"smoother RMSE on the simulated bag: {err:.3f} m")
    assert err < 0.30


@pytest.mark.slow
def test_evo_matches_every_smoother_pose(tmp_path):
    """groundtruth.tum + smoother.tum read by evo with the t_max_diff metrics.json names."""
    config = cli.default_config("smoother")
    m = rundir.run_one(config, load_log_for(config), tmp_path)
    tmax = json.loads((tmp_path / "metrics.json").read_text())["evo_t_max_diff_s"]
    assert 0.01 < tmax < 0.2  # evo's default (0.01 s) would drop most smoother poses

    def evo(*extra):
        cmd = ["evo_ape", "tum", "groundtruth.tum", "smoother.tum", "-v", *extra]
        text = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, check=True).stdout
        found = re.search(r"Found (\d+) of max\. (\d+)", text)
        return int(found.group(1)), float(re.search(r"rmse\s+([0-9.]+)", text).group(1))

    n_default, _ = evo()
    n, rmse_evo = evo("--t_max_diff", f"{math.ceil(tmax * 1000) / 1000:.3f}")
    assert n == m["poses"] > n_default
    # evo pairs nearest stamps, odofuse interpolates the ground truth: close, not equal
    assert rmse_evo == pytest.approx(m["ate_rmse_m"], rel=0.05)


def test_groundtruth_tum_from_a_bag_run(ekf_run, robot, tmp_path):
    _, cfg = ekf_run
    log = load_log_for(cfg)
    gt = Stream("groundtruth", "sim", robot.t + T0, ("x", "y", "theta"), robot.truth)
    m = rundir.run_one(
        dataclasses.replace(cfg, estimator="dead_reckoning"),
        dataclasses.replace(log, groundtruth=gt),
        tmp_path,
    )
    assert (tmp_path / "groundtruth.tum").exists() and (tmp_path / "dead_reckoning.tum").exists()
    assert m["poses"] == len(log.streams["wheels"])
    from odofuse.outputs import read_tum

    back = read_tum(tmp_path / "groundtruth.tum")
    np.testing.assert_allclose(back.poses[:, :2], robot.truth[:, :2], atol=1e-9)
    # the estimate's stamps are ground-truth stamps: evo's default t_max_diff suffices
    assert json.loads((tmp_path / "metrics.json").read_text())["evo_t_max_diff_s"] < 1e-5
