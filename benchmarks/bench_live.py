"""``odofuse live``: latency from a reading's arrival to the published Odometry, and CPU share
(issue 27: targets p99 < 5 ms, < 20 % of one core).

A player process publishes, in real time over Zenoh on 127.0.0.1 (rmw_zenoh's wire format, no
multicast scouting), a differential robot driving a circle: ``/joint_states`` at 100 Hz,
``/imu/data`` at 200 Hz (yaw rate, with its covariance) and ``/fix`` at 10 Hz (NavSatFix,
0.5 m). This process runs the component (an EKF, the gyro bias calibrated) on its own Zenoh
session and publishes ``/odometry/filtered``, ``/tf`` and ``/diagnostics`` as ``odofuse
live`` does. Printed:

* latency per JointState (the reading that makes an Odometry): from the sample's arrival in
  this process (the Zenoh callback) to the return of the Odometry's and TF's ``put``;
  median, 99th percentile, largest;
* the same for IMU and GPS readings (arrival to the reading being in the filter);
* ``handle()`` alone: the component's own work per message (decode, filter, publish);
  the difference to the latency is time in the inbox, i.e. this process waiting for a core
  (on a shared machine the scheduler, not the component, sets the tail);
* CPU share of one core: this process's CPU time (all its threads, Zenoh's included) over
  the wall time of the run, and the machine's load average.

Run: ``python benchmarks/bench_live.py [--seconds S]`` (default 30 s of real time).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATUM = (45.0, 9.0)
R, B, V, W = 0.1, 0.5, 0.5, 0.1  # wheel radius, track, speed (m/s), yaw rate (rad/s)
CONFIG = """\
log: {log}
robot: {{drive: differential, wheel_radius: 0.1, track_width: 0.5}}
estimator: ekf
sensors:
  gps: {{datum: [45.0, 9.0]}}
  gyro: {{calibrate: true}}
live:
  listen: [tcp/127.0.0.1:{port}]
  connect: []
  multicast_scouting: false
  joints: {{left: left_wheel_joint, right: right_wheel_joint}}
"""


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def player(port: int, seconds: float) -> None:
    """Publish the robot's readings in real time (the --play side)."""
    import pymap3d

    from odofuse.declarations.live import LiveOptions
    from odofuse.live import rmw
    from odofuse.live.transport import Node, wait_matched

    live = LiveOptions(connect=(f"tcp/127.0.0.1:{port}",), listen=(), multicast_scouting=False)
    node = Node(live, name="bench_player")
    ts = rmw.typestore("jazzy")
    T = ts.types
    qos = rmw.Qos()
    types = {
        "/joint_states": "sensor_msgs/msg/JointState",
        "/imu/data": "sensor_msgs/msg/Imu",
        "/fix": "sensor_msgs/msg/NavSatFix",
    }
    pubs = {t: node.publisher(t, ty, qos) for t, ty in types.items()}
    wait_matched(list(pubs.values()), 10.0)
    rng = np.random.default_rng(11)
    events = sorted(
        [(k / 100, "/joint_states") for k in range(int(seconds * 100))]
        + [(k / 200, "/imu/data") for k in range(int(seconds * 200))]
        + [(k / 10, "/fix") for k in range(int(seconds * 10))]
    )
    wl, wr = (V - W * B / 2) / R, (V + W * B / 2) / R
    v3 = T["geometry_msgs/msg/Vector3"]
    start_wall = time.time()
    start = time.monotonic()
    for t, topic in events:
        delay = t - (time.monotonic() - start)
        if delay > 0:
            time.sleep(delay)
        ns = int((start_wall + t) * 1e9)
        header = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id="" if topic == "/joint_states" else "base_link",
        )
        if topic == "/joint_states":
            msg = T[types[topic]](
                header=header,
                name=["left_wheel_joint", "right_wheel_joint"],
                position=np.array([wl * t, wr * t]),
                velocity=np.zeros(0),
                effort=np.zeros(0),
            )
        elif topic == "/imu/data":
            oc = np.zeros(9)
            oc[0] = -1.0
            msg = T[types[topic]](
                header=header,
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=oc,
                angular_velocity=v3(x=0.0, y=0.0, z=W + rng.normal(0.0, 0.01)),
                angular_velocity_covariance=np.diag([1e-4] * 3).reshape(-1),
                linear_acceleration=v3(x=0.0, y=0.0, z=9.81),
                linear_acceleration_covariance=np.zeros(9),
            )
        else:
            th = W * t
            x, y = V / W * math.sin(th), V / W * (1 - math.cos(th))
            lat, lon, _ = pymap3d.enu2geodetic(
                x + rng.normal(0, 0.5), y + rng.normal(0, 0.5), 0.0, *DATUM, 0.0
            )
            cov = np.zeros(9)
            cov[0] = cov[4] = 0.25
            cov[8] = 1.0
            msg = T[types[topic]](
                header=header,
                status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                latitude=float(lat),
                longitude=float(lon),
                altitude=0.0,
                position_covariance=cov,
                position_covariance_type=2,
            )
        pubs[topic].put(ts.serialize_cdr(msg, types[topic]))
    time.sleep(0.5)
    node.close()


def component(port: int, seconds: float) -> dict:
    from odofuse.config import load_config
    from odofuse.live.run import Runner, prepare

    folder = Path(tempfile.mkdtemp(prefix="bench_live."))
    (folder / "empty").mkdir()
    cfg_path = folder / "live.yaml"
    cfg_path.write_text(CONFIG.format(log="empty", port=port))
    config, log = prepare(load_config(cfg_path), None)
    runner = Runner(config, log)
    runner.component.start()
    proc = subprocess.Popen(
        [sys.executable, __file__, "--play", str(port), "--seconds", str(seconds)]
    )
    lat: dict[str, list] = {"/joint_states": [], "/imu/data": [], "/fix": []}
    cpu0, wall0 = time.process_time(), time.monotonic()
    first = None
    handle_s = []
    deadline = time.monotonic() + seconds + 30.0
    try:
        while time.monotonic() < deadline:
            try:
                topic, payload, arrival, _ = runner.inbox.get(timeout=2.0 if first else 20.0)
            except Exception:
                break  # the player finished
            if first is None:
                first = time.monotonic()
                cpu0, wall0 = time.process_time(), first
            t_h = time.perf_counter()
            runner.component.handle(topic, payload)
            t_h = time.perf_counter() - t_h
            handle_s.append(t_h)
            runner.handled += 1
            lat[topic].append(time.monotonic_ns() - arrival)
        wall = time.monotonic() - wall0
        cpu = time.process_time() - cpu0
    finally:
        proc.wait(timeout=60)
        runner.close()
    out = {"cpu_share": cpu / wall, "wall_s": wall, "bad": runner.component.bad}
    for topic, v in lat.items():
        a = np.asarray(v, dtype=float) / 1e6
        out[topic] = {
            "n": int(a.size),
            "median_ms": float(np.median(a)) if a.size else math.nan,
            "p99_ms": float(np.percentile(a, 99)) if a.size else math.nan,
            "max_ms": float(a.max()) if a.size else math.nan,
        }
    out["published"] = runner.component.published
    h = np.asarray(handle_s) * 1e3
    out["handle_ms"] = (float(np.median(h)), float(np.percentile(h, 99)), float(h.max()))
    out["status"] = runner.component.health().status
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--play", type=int, metavar="PORT", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.play:
        player(args.play, args.seconds)
        return 0
    res = component(free_port(), args.seconds)
    print(f"odofuse live, {args.seconds:g} s real time, EKF (100 Hz wheels, 200 Hz IMU, 10 Hz GPS)")
    print("| reading | messages | median [ms] | p99 [ms] | max [ms] |")
    print("| --- | --- | --- | --- | --- |")
    names = {
        "/joint_states": "JointState -> Odometry+TF put",
        "/imu/data": "Imu",
        "/fix": "NavSatFix",
    }
    for topic, name in names.items():
        r = res[topic]
        print(
            f"| {name} | {r['n']} | {r['median_ms']:.3f} | {r['p99_ms']:.3f} | {r['max_ms']:.3f} |"
        )
    hm, hp, hx = res["handle_ms"]
    print(f"handle() alone, median / p99 / max [ms]: {hm:.3f} / {hp:.3f} / {hx:.3f}")
    print(f"CPU share of one core: {100 * res['cpu_share']:.1f} % over {res['wall_s']:.1f} s")
    load = os.getloadavg()
    print(f"load average during the run: {load[0]:.1f} (1 min) on {os.cpu_count()} cores")
    print(f"published {res['published']}, status {res['status']}, skipped {json.dumps(res['bad'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
