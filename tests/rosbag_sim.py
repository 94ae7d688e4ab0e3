"""A simulated differential robot recorded as a ROS 2 bag (for tests; written with rosbags).

The one place that imports the project's simulator (:func:`simulate_robot`): when the
simulator moves, fix the import here.

Topics (all stamps on the simulated clock + ``T0``):

* ``/joint_states`` JointState 50 Hz, joints ``right_wheel_joint``, ``left_wheel_joint`` (in
  that order), ``position`` (or only ``velocity`` with ``velocity_only``);
* ``/imu/data`` Imu 100 Hz, frame ``imu_link``: gyro with bias ``GYRO_BIAS``, its
  ``angular_velocity_covariance``; no orientation (``orientation_covariance[0] = -1``);
* ``/imu2/data`` Imu 50 Hz, frame ``imu2_link`` (mounted yawed by ``IMU2_YAW``): unbiased gyro
  and an orientation (AHRS yaw) with its covariance;
* ``/fix`` NavSatFix 1 Hz, frame ``gps_link`` (lever arm ``GPS_LEVER``), covariance type 2,
  two outliers of ``OUTLIER_M`` metres;
* ``/wheel/odom`` Odometry 50 Hz (diff_drive_controller style: dead reckoning with the nominal
  geometry, constant pose covariance, twist covariance);
* ``/tf_static``: ``base_link -> imu_link, imu2_link, gps_link``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

T0 = 1_700_000_000.0
DATUM = (45.0, 9.0, 0.0)
GYRO_BIAS = 0.02  # rad/s
GYRO_SIGMA = 0.01  # rad/s, per 100 Hz sample
GPS_SIGMA = 0.5  # m
OUTLIER_M = 25.0
GPS_LEVER = (0.3, 0.1)
IMU2_YAW = 0.5 * math.pi
IMU2_YAW_SIGMA = 0.05
GEOMETRY = {"wheel_radius": 0.1, "track_width": 0.5}
#: The ten-line config a robot_localization user writes for the bag (docs/ros2.md shows the
#: same); ``CONFIG.format(bag=..., estimator=...)``.
CONFIG = """\
log:
  path: {bag}
  topics: {{gyro: [/imu/data, /imu2/data]}}
  joints: {{left: left_wheel_joint, right: right_wheel_joint}}
robot: {{drive: differential, wheel_radius: 0.1, track_width: 0.5}}
estimator: {estimator}
sensors:
  gps: {{datum: [45.0, 9.0]}}
  gyro: {{calibrate: true}}
  compass_2: {{}}
"""


@dataclass(frozen=True)
class SimRobot:
    t: np.ndarray  # (N+1,) simulation clock, 100 Hz, from 0
    truth: np.ndarray  # (N+1, 3)
    wheels: np.ndarray  # (N+1, 2) cumulative measured wheel angles [left, right]
    gyro: np.ndarray  # (N+1,) yaw rate measured by /imu/data (NaN at index 0)
    seed: int


def simulate_robot(seed: int = 3) -> SimRobot:
    """A 10 m square driven twice with systematic and random wheel errors (100 Hz)."""
    from odofuse.teaching.simulate import GyroSpec, Scenario, SystematicErrors, WheelNoise, simulate

    sc = Scenario(
        drive="differential",
        geometry=GEOMETRY,
        path={"kind": "square", "side": 10.0, "speed": 0.5, "laps": 2, "corner_radius": 0.5},
        dt=0.01,
        systematic=SystematicErrors(E_d=1.01, E_b=1.03),
        wheel_noise=WheelNoise(k=1e-4),
        gyro=GyroSpec(sigma=GYRO_SIGMA, bias=GYRO_BIAS),
        seed=seed,
    )
    sim = simulate(sc)
    w = sim.streams["wheels"]
    gyro = np.full(len(sim.t), np.nan)
    g = sim.streams["gyro"]
    gyro[np.searchsorted(sim.t, g.t - 1e-9)] = g["wz"]
    return SimRobot(sim.t, sim.truth, np.column_stack([w["left"], w["right"]]), gyro, seed)


def write_robot_bag(path, robot: SimRobot, storage: str = "mcap", velocity_only: bool = False):
    """Write ``robot`` as a ROS 2 bag folder at ``path`` (``storage``: ``mcap`` or ``sqlite3``)."""
    import pymap3d
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from odofuse import se2

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    rng = np.random.default_rng(robot.seed + 100)
    v3 = T["geometry_msgs/msg/Vector3"]

    def header(t, frame):
        ns = int(round((T0 + t) * 1e9))
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id=frame,
        )

    def quat(yaw):
        return T["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
        )

    def tf(child, x, y, yaw):
        return T["geometry_msgs/msg/TransformStamped"](
            header=header(0.0, "base_link"),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=v3(x=x, y=y, z=0.2), rotation=quat(yaw)
            ),
        )

    msgs: list[tuple[float, str, object]] = []
    tfm = T["tf2_msgs/msg/TFMessage"](
        transforms=[
            tf("imu_link", 0.0, 0.0, 0.0),
            tf("imu2_link", 0.1, 0.0, IMU2_YAW),
            tf("gps_link", *GPS_LEVER, 0.0),
        ]
    )
    msgs.append((0.0, "/tf_static", tfm))
    n = len(robot.t)
    r, b = GEOMETRY["wheel_radius"], GEOMETRY["track_width"]
    # diff_drive_controller: dead reckoning with the nominal geometry, 50 Hz
    odo = np.zeros(3)
    prev = robot.wheels[0]
    cov6 = np.diag([1e-3, 1e-3, 1e6, 1e6, 1e6, 1e-3]).reshape(-1)
    tw6 = np.diag([1e-4, 1e-6, 1e6, 1e6, 1e6, 1e-3]).reshape(-1)
    for k in range(0, n, 2):
        t = robot.t[k]
        dl, dr = (robot.wheels[k] - prev) * r
        prev = robot.wheels[k]
        odo = se2.compose(odo, se2.exp([(dr - dl) / b, 0.5 * (dl + dr), 0.0]))
        if velocity_only:
            kk = max(k - 1, 0)
            vel = (robot.wheels[min(k + 1, n - 1)] - robot.wheels[kk]) / (
                robot.t[min(k + 1, n - 1)] - robot.t[kk]
            )
            js = T["sensor_msgs/msg/JointState"](
                header=header(t, ""),
                name=["right_wheel_joint", "left_wheel_joint"],
                position=np.zeros(0),
                velocity=np.array([vel[1], vel[0]]),
                effort=np.zeros(0),
            )
        else:
            js = T["sensor_msgs/msg/JointState"](
                header=header(t, ""),
                name=["right_wheel_joint", "left_wheel_joint"],
                position=np.array([robot.wheels[k, 1], robot.wheels[k, 0]]),
                velocity=np.zeros(0),
                effort=np.zeros(0),
            )
        msgs.append((t, "/joint_states", js))
        pose = T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=odo[0], y=odo[1], z=0.0),
                orientation=quat(odo[2]),
            ),
            covariance=cov6,
        )
        twist = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](
                linear=v3(x=0.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0)
            ),
            covariance=tw6,
        )
        msgs.append(
            (
                t,
                "/wheel/odom",
                T["nav_msgs/msg/Odometry"](
                    header=header(t, "odom"), child_frame_id="base_link", pose=pose, twist=twist
                ),
            )
        )

    def imu(t, frame, wz, wz_var, yaw=None, yaw_var=-1.0):
        oc = np.zeros(9)
        oc[0] = -1.0 if yaw is None else 1e-3
        if yaw is not None:
            oc[4], oc[8] = 1e-3, yaw_var
        return T["sensor_msgs/msg/Imu"](
            header=header(t, frame),
            orientation=quat(0.0 if yaw is None else yaw),
            orientation_covariance=oc,
            angular_velocity=v3(x=0.0, y=0.0, z=wz),
            angular_velocity_covariance=np.diag([wz_var] * 3).reshape(-1),
            linear_acceleration=v3(x=0.0, y=0.0, z=9.81),
            linear_acceleration_covariance=np.zeros(9),
        )

    for k in range(1, n):
        msgs.append(
            (robot.t[k], "/imu/data", imu(robot.t[k], "imu_link", robot.gyro[k], GYRO_SIGMA**2))
        )
    true_rate = np.diff(np.unwrap(robot.truth[:, 2])) / np.diff(robot.t)
    for k in range(2, n, 2):
        wz = true_rate[k - 1] + rng.normal(0.0, 0.02)
        yaw = robot.truth[k, 2] + IMU2_YAW + rng.normal(0.0, IMU2_YAW_SIGMA)
        msgs.append(
            (
                robot.t[k],
                "/imu2/data",
                imu(robot.t[k], "imu2_link", wz, 0.02**2, yaw, IMU2_YAW_SIGMA**2),
            )
        )
    fix_idx = np.arange(0, n, 100)
    outliers = set(fix_idx[[len(fix_idx) // 3, 2 * len(fix_idx) // 3]].tolist())
    for k in fix_idx:
        p = robot.truth[k]
        c, s = math.cos(p[2]), math.sin(p[2])
        e = p[0] + c * GPS_LEVER[0] - s * GPS_LEVER[1] + rng.normal(0.0, GPS_SIGMA)
        nn = p[1] + s * GPS_LEVER[0] + c * GPS_LEVER[1] + rng.normal(0.0, GPS_SIGMA)
        if int(k) in outliers:
            e += OUTLIER_M
        lat, lon, alt = pymap3d.enu2geodetic(e, nn, 0.0, *DATUM)
        cov = np.zeros(9)
        cov[0] = cov[4] = GPS_SIGMA**2
        cov[8] = 4 * GPS_SIGMA**2
        msgs.append(
            (
                robot.t[k],
                "/fix",
                T["sensor_msgs/msg/NavSatFix"](
                    header=header(robot.t[k], "gps_link"),
                    status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                    latitude=float(lat),
                    longitude=float(lon),
                    altitude=float(alt),
                    position_covariance=cov,
                    position_covariance_type=2,
                ),
            )
        )
    types = {
        "/tf_static": "tf2_msgs/msg/TFMessage",
        "/joint_states": "sensor_msgs/msg/JointState",
        "/wheel/odom": "nav_msgs/msg/Odometry",
        "/imu/data": "sensor_msgs/msg/Imu",
        "/imu2/data": "sensor_msgs/msg/Imu",
        "/fix": "sensor_msgs/msg/NavSatFix",
    }
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    msgs.sort(key=lambda m: m[0])
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = {tp: w.add_connection(tp, ty, typestore=ts) for tp, ty in types.items()}
        for t, topic, msg in msgs:
            w.write(conns[topic], int(round((T0 + t) * 1e9)), ts.serialize_cdr(msg, types[topic]))
    return path
