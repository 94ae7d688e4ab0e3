"""``odofuse live`` (issue 27): rmw_zenoh's wire format, the component's correctness, and a
replay over two Zenoh sessions on loopback (no multicast scouting) against ``odofuse run``.

The bag is tests/rosbag_sim.py's robot, cut to 8 s (JointState 50 Hz, two IMUs, NavSatFix
1 Hz, /tf_static) so that each test runs in seconds.
"""

from __future__ import annotations

import dataclasses
import math
import socket
import time

import numpy as np
import pytest

pytest.importorskip("rosbags")
zenoh = pytest.importorskip("zenoh")

from rosbag_sim import CONFIG, simulate_robot, write_robot_bag  # noqa: E402

from odofuse import se2  # noqa: E402
from odofuse.config import load_config  # noqa: E402
from odofuse.declarations.live import LiveOptions  # noqa: E402
from odofuse.live import rmw  # noqa: E402
from odofuse.live.component import Component, map_odom_correction  # noqa: E402
from odofuse.live.run import prepare, replay_messages, run_live  # noqa: E402
from odofuse.outputs import read_trajectory_csv  # noqa: E402

N = 801  # 8 s of the 100 Hz simulation


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    r = simulate_robot()
    short = dataclasses.replace(r, t=r.t[:N], truth=r.truth[:N], wheels=r.wheels[:N])
    short = dataclasses.replace(short, gyro=r.gyro[:N])
    base = tmp_path_factory.mktemp("livebag")
    return write_robot_bag(base / "bag", short, "mcap")


def config_file(tmp_path, bag, live: str = "{transport: none}"):
    p = tmp_path / "run.yaml"
    p.write_text(CONFIG.format(bag=str(bag), estimator="ekf") + f"live: {live}\n")
    return load_config(p)


def collect(config, bag):
    """A transport-free component on the bag's messages (replay order); its outputs."""
    config, log = prepare(config, str(bag))
    out = []
    comp = Component(config, lambda o, ty, m: out.append((o, m)), log)
    msgs = replay_messages(str(bag), comp)
    return comp, msgs, out


# ----------------------------------------------------------------------- wire format
#: Published RIHS01 values, as ``ros2 topic info -v`` prints them on Jazzy and as rmw_zenoh
#: key expressions carry them: std_msgs/String from rmw_zenoh's key expression example
#: (``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``, docs/design.md on rolling),
#: tf2_msgs/TFMessage from a ``ros2 topic info /tf --verbose`` transcript on Jazzy
#: ("Topic type hash: RIHS01_e369..."), nav_msgs/Odometry and sensor_msgs/NavSatFix from the
#: golden hashes that rosidl-generated code asserts (CHECK_GOLDEN_HASH(Odometry, ...)).
PUBLISHED = {
    "std_msgs/msg/String": (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    ),
    "tf2_msgs/msg/TFMessage": (
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
    ),
    "nav_msgs/msg/Odometry": (
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
    ),
    "sensor_msgs/msg/NavSatFix": (
        "RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404"
    ),
}


@pytest.mark.parametrize("msgtype", sorted(PUBLISHED))
def test_type_hashes_match_published(msgtype):
    for distro in ("jazzy", "kilted"):
        assert rmw.type_hash(msgtype, distro) == PUBLISHED[msgtype]
    assert rmw.type_hash(msgtype, "humble") == rmw.NO_TYPE_HASH


def test_key_expressions_tokens_attachment():
    key = rmw.topic_keyexpr(0, "/chatter", "std_msgs/msg/String", "jazzy")
    assert key == "0/chatter/std_msgs::msg::dds_::String_/" + PUBLISHED["std_msgs/msg/String"]
    assert rmw.topic_keyexpr(3, "/odometry/filtered", "nav_msgs/msg/Odometry", "humble") == (
        "3/odometry/filtered/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"
    )
    assert rmw.Qos().keyexpr() == "::,:,:,:,,"  # rmw_qos_profile_default
    assert rmw.Qos(depth=100).keyexpr() == "::,100:,:,:,,"
    assert rmw.Qos(transient_local=True, depth=1).keyexpr() == ":1:,1:,:,:,,"
    assert rmw.Qos(reliable=False, depth=5).keyexpr() == "2::,5:,:,:,,"
    tok = rmw.entity_token(
        0, "abc", 0, 7, "MP", "", "odofuse", "/tf", "tf2_msgs/msg/TFMessage", "jazzy", rmw.Qos()
    )
    assert tok == (
        "@ros2_lv/0/abc/0/7/MP/%/%/odofuse/%tf/tf2_msgs::msg::dds_::TFMessage_/"
        + PUBLISHED["tf2_msgs/msg/TFMessage"]
        + "/::,:,:,:,,"
    )
    assert rmw.node_token(0, "abc", 0, "/robot1", "odofuse") == (
        "@ros2_lv/0/abc/0/0/NN/%/%robot1/odofuse"
    )
    gid = bytes(range(16))
    att = rmw.attachment(42, 1_700_000_000_123_456_789, gid)
    assert len(att) == 33 and att[16] == 16
    assert rmw.parse_attachment(att) == (42, 1_700_000_000_123_456_789, gid)


def test_environment_variables(monkeypatch, tmp_path):
    monkeypatch.setenv("ROS_DOMAIN_ID", "17")
    assert rmw.domain_id(None) == 17 and rmw.domain_id(3) == 3
    monkeypatch.setenv("ROS_DOMAIN_ID", "x")
    with pytest.raises(Exception, match="ROS_DOMAIN_ID"):
        rmw.domain_id(None)
    f = tmp_path / "z.json5"
    f.write_text('{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:9"]}}')
    monkeypatch.setenv("ZENOH_SESSION_CONFIG_URI", str(f))
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", 'listen/endpoints=["tcp/127.0.0.1:0"]')
    conf = rmw.session_config(LiveOptions())
    assert '"client"' in conf.get_json("mode")
    assert "127.0.0.1:0" in conf.get_json("listen/endpoints")
    conf = rmw.session_config(LiveOptions(mode="peer"))  # the live: block on top
    assert '"peer"' in conf.get_json("mode")


def test_config_without_live_block(tmp_path, bag):
    p = tmp_path / "plain.yaml"
    p.write_text(CONFIG.format(bag=str(bag), estimator="ekf"))
    config = load_config(p)
    assert config.live == LiveOptions()
    comp = Component(*prepare(config, str(bag))[:1], lambda *a: None)
    topics = {(i.topic, i.kind) for i in comp.inputs}
    assert topics == {
        ("/joint_states", "wheels"),
        ("/imu/data", "gyro"),
        ("/imu2/data", "gyro"),
        ("/fix", "gps"),
    }
    assert comp.outputs["odometry"] == "/odometry/filtered"


# ----------------------------------------------------------------------- correctness
def _poses(out):
    return np.array(
        [
            [
                m.pose.pose.position.x,
                m.pose.pose.position.y,
                2 * math.atan2(m.pose.pose.orientation.z, m.pose.pose.orientation.w),
            ]
            for o, m in out
            if o == "odometry"
        ]
    )


def _late_and_in_order(tmp_path, bag):
    config = config_file(tmp_path, bag)
    comp, msgs, out = collect(config, bag)
    for topic, _, payload, _ in msgs:
        comp.handle(topic, payload)
    ref = comp.loc.pose()
    # each topic with its own latency (the late window is 0.5 s by default): the readings
    # arrive after the odometry that covers them and out of order across topics
    delay = {"/joint_states": 0.0, "/imu/data": 0.05, "/imu2/data": 0.12, "/fix": 0.3}
    # (a reading stamped at the start time itself goes to the initial state: not delayed,
    # since no odometry step covers it for a replay)
    t0 = msgs[0][3]
    delayed = [
        (t + (delay[topic] if t > t0 else 0.0), i, topic, p)
        for i, (topic, _, p, t) in enumerate(msgs)
    ]
    delayed.sort()
    comp2, _, _ = collect(config, bag)
    for _, _, topic, payload in delayed:
        comp2.handle(topic, payload)
    return comp, comp2, msgs, ref


def test_out_of_order_within_lag_equals_in_order(tmp_path, bag):
    comp, comp2, msgs, ref = _late_and_in_order(tmp_path, bag)
    # a late reading takes its on-time place among readings of its stamp (the config's stream
    # order, not arrival order): the same estimate, every reading used, none dropped
    np.testing.assert_allclose(comp2.loc.pose(), ref, atol=1e-9)
    assert comp2.loc.used == comp.loc.used
    assert not any(comp2.loc.dropped_late.values())
    # a GPS fix 2 s late is dropped, counted and reported
    gps = [(topic, p) for topic, _, p, t in msgs if topic == "/fix"]
    comp2.handle(*gps[2])
    assert comp2.loc.dropped_late["gps"] == 1
    values = dict(comp2.diagnostic_values(comp2.health()))
    assert values["dropped_late/gps"] == 1


def test_health_before_the_first_odometry_is_waiting(tmp_path, bag):
    config, log = prepare(config_file(tmp_path, bag, "{transport: none}"), str(bag))
    comp = Component(config, lambda o, ty, m: None, log)
    h = comp.health()
    assert h.status == "degraded" and [f.check for f in h.findings] == ["waiting"]


def test_timeout_raised_and_recovered(tmp_path, bag):
    config = config_file(tmp_path, bag, "{transport: none, timeout: 1.5}")
    comp, msgs, out = collect(config, bag)
    fixes = [t for topic, _, _, t in msgs if topic == "/fix"]
    gap = (fixes[2], fixes[5])  # the GPS silent from its 3rd to its 6th fix
    states = []
    for topic, _, payload, t in msgs:
        if topic == "/fix" and gap[0] < t < gap[1]:
            continue
        comp.handle(topic, payload)
        found = [f for f in comp.health().findings if f.check == "timeout"]
        states.append((t, bool(found)))
    raised = [t for t, on in states if on]
    assert raised and raised[0] <= gap[0] + 1.5 + 0.021  # within its period (+ one step)
    assert raised[0] > gap[0] + 1.5 - 1e-9
    assert not states[-1][1]  # recovered after the fix at gap[1]
    assert comp.timeouts_raised == {"gps": 1}
    assert comp.health().status == "ok" or all(f.check != "timeout" for f in comp.health().findings)


def test_tf_continuity_and_map_odom_correction(tmp_path, bag):
    config = config_file(tmp_path, bag)
    comp, msgs, out = collect(config, bag)
    rows = []
    for topic, _, payload, _ in msgs:
        before = None if comp.loc is None else (comp.loc.pose(), comp.loc.odom_pose())
        n = comp.steps
        comp.handle(topic, payload)
        if comp.steps > n and before is not None:
            rows.append((*before, comp.loc.pose(), comp.loc.odom_pose(), comp.loc.map_to_odom()))
    jumps = 0
    for prev_pose, prev_odom, pose, odom, map_odom in rows:
        inc = se2.compose(se2.inverse(prev_odom), odom)
        # odom -> base_link moves by the step's own increment: no jump
        assert np.hypot(*inc[:2]) < 0.05 and abs(inc[2]) < 0.05
        C = map_odom_correction(prev_pose, pose, inc)
        prev_map_odom = se2.compose(prev_pose, se2.inverse(prev_odom))
        # map -> odom moves by exactly the rigid correction of the step's updates
        np.testing.assert_allclose(se2.compose(C, prev_map_odom)[:2], map_odom[:2], atol=1e-9)
        assert abs(se2.wrap(se2.compose(C, prev_map_odom)[2] - map_odom[2])) < 1e-9
        jumps += bool(np.abs(C).max() > 1e-12)
    assert jumps > 0  # GPS and gyro corrections happened
    tfs = [m for o, m in out if o == "tf"]
    assert [t.child_frame_id for t in tfs[0].transforms] == ["odom", "base_link"]


def test_reset_equals_fresh_start(tmp_path, bag):
    config = config_file(tmp_path, bag)
    comp, msgs, out = collect(config, bag)
    T = comp.T
    t_reset = msgs[len(msgs) // 2][3]
    pose = [1.0, -2.0, 0.3]
    cov = np.zeros(36)
    cov[0] = cov[7] = 0.04
    cov[35] = 0.01
    reset = T["geometry_msgs/msg/PoseWithCovarianceStamped"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=int(t_reset), nanosec=0), frame_id="map"
        ),
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=1.0, y=-2.0, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(0.15), w=math.cos(0.15)
                ),
            ),
            covariance=cov,
        ),
    )
    payload = comp.ts.serialize_cdr(reset, "geometry_msgs/msg/PoseWithCovarianceStamped")
    half = len(msgs) // 2
    for topic, _, p, _ in msgs[:half]:
        comp.handle(topic, p)
    comp.handle("/set_pose", payload)
    for topic, _, p, _ in msgs[half:]:
        comp.handle(topic, p)
    # a fresh start from that pose with initial.sigma = the reset covariance's
    init = dataclasses.replace(config.initial, pose=tuple(pose), sigma=(0.2, 0.2, 0.1))
    fresh_cfg = dataclasses.replace(config, initial=init)
    fresh, _, _ = collect(fresh_cfg, bag)
    for topic, _, p, _ in msgs[half:]:
        fresh.handle(topic, p)
    np.testing.assert_array_equal(comp.loc.pose(), fresh.loc.pose())
    np.testing.assert_array_equal(comp.loc.covariance(), fresh.loc.covariance())


def test_bad_messages_counted_never_crash(tmp_path, bag):
    config = config_file(tmp_path, bag)
    comp, msgs, out = collect(config, bag)
    ts = comp.ts
    for topic, _, p, _ in msgs[:200]:
        comp.handle(topic, p)
    ref = comp.loc.pose()
    imu = next(p for topic, _, p, _ in msgs if topic == "/imu/data")
    m = ts.deserialize_cdr(imu, "sensor_msgs/msg/Imu")
    bad = []
    wrong = dataclasses.replace(m, header=dataclasses.replace(m.header, frame_id="camera_link"))
    bad.append(("/imu/data", wrong, "sensor_msgs/msg/Imu"))
    nan = dataclasses.replace(
        m, angular_velocity=dataclasses.replace(m.angular_velocity, z=float("nan"))
    )
    bad.append(("/imu/data", nan, "sensor_msgs/msg/Imu"))
    cov = np.diag([1.0, 1.0, -1.0]).reshape(-1)
    bad.append(
        (
            "/imu/data",
            dataclasses.replace(m, angular_velocity_covariance=cov),
            "sensor_msgs/msg/Imu",
        )
    )
    js = next(p for topic, _, p, _ in msgs if topic == "/joint_states")  # the first: t0
    for topic, msg, ty in bad:
        comp.handle(topic, ts.serialize_cdr(msg, ty))
    comp.handle("/joint_states", js)  # time going backwards
    comp.handle("/imu/data", b"\x00\x01garbage")
    assert comp.bad == {
        "wrong_frame": 1,
        "nan": 1,
        "covariance": 1,
        "time_backwards": 1,
        "undecodable": 1,
    }
    np.testing.assert_array_equal(comp.loc.pose(), ref)  # all skipped
    values = dict(comp.diagnostic_values(comp.health()))
    assert values["bad/covariance"] == 1 and values["bad/time_backwards"] == 1
    # the last skipped message, named for the operator: the garbage sent last
    assert values["bad/last"].startswith("/imu/data: Could not deserialize 'sensor_msgs/msg/Imu'")
    for topic, _, p, _ in msgs[200:]:  # and it goes on
        comp.handle(topic, p)
    assert comp.steps == len([1 for topic, *_ in msgs if topic == "/joint_states"]) - 1


# ----------------------------------------------------------------------- over Zenoh
def test_replay_over_zenoh_equals_odofuse_run(tmp_path, bag):
    """A subscriber session decodes every output of ``odofuse live --replay`` (player and
    component on a second and third session, tcp/127.0.0.1 only, no multicast) and compares
    it with ``odofuse run`` on the same bag; ``-o`` writes the same trajectory."""
    from odofuse.cli import main
    from odofuse.live.transport import Node

    port_sub, port_live = free_port(), free_port()
    live = (
        f"{{listen: [tcp/127.0.0.1:{port_live}], connect: [tcp/127.0.0.1:{port_sub}], "
        "multicast_scouting: false}"
    )
    config = config_file(tmp_path, bag, live)
    sub = Node(
        LiveOptions(listen=(f"tcp/127.0.0.1:{port_sub}",), connect=(), multicast_scouting=False),
        name="checker",
    )
    got: dict[str, list] = {"odometry": [], "tf": [], "tf_static": [], "diagnostics": []}
    types = {
        "odometry": ("/odometry/filtered", "nav_msgs/msg/Odometry"),
        "tf": ("/tf", "tf2_msgs/msg/TFMessage"),
        "tf_static": ("/tf_static", "tf2_msgs/msg/TFMessage"),
        "diagnostics": ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
    }
    ts = rmw.typestore("jazzy")
    for name, (topic, ty) in types.items():
        qos = rmw.Qos(transient_local=name == "tf_static", depth=1 if name == "tf_static" else 10)

        def cb(t, payload, ns, att, name=name, ty=ty):
            got[name].append((ts.deserialize_cdr(payload, ty), att))

        sub.subscribe(topic, ty, qos, cb)
    try:
        out_live = tmp_path / "out_live"
        summary = run_live(config, replay=str(bag), out=str(out_live))
        deadline = time.monotonic() + 10.0
        while len(got["odometry"]) < summary["published"] and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        sub.close()
    assert summary["bad"] == {} and summary["handled"] == summary["messages"]
    assert main(["run", str(config.source), "-o", str(tmp_path / "out_run")]) == 0
    run_traj = read_trajectory_csv(tmp_path / "out_run" / "trajectory.csv")
    live_traj = read_trajectory_csv(out_live / "trajectory.csv")
    assert (tmp_path / "out_run" / "trajectory.csv").read_bytes() == (
        out_live / "trajectory.csv"
    ).read_bytes()
    # every published estimate, decoded from the wire, is odofuse run's pose at its stamp
    odo = got["odometry"]
    assert len(odo) == len(run_traj) - 1 == summary["published"]
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m, _ in odo])
    np.testing.assert_allclose(stamps, run_traj.t[1:], atol=1e-6)
    poses = _poses([("odometry", m) for m, _ in odo])
    np.testing.assert_allclose(poses[:, :2], run_traj.poses[1:, :2], atol=1e-12)
    np.testing.assert_allclose(se2.wrap(poses[:, 2] - run_traj.poses[1:, 2]), 0.0, atol=1e-12)
    cov = np.array(
        [np.asarray(m.pose.covariance).reshape(6, 6)[:, [0, 1, 5]][[0, 1, 5]] for m, _ in odo]
    )
    np.testing.assert_allclose(cov, live_traj.covariances[1:], rtol=1e-12, atol=1e-18)
    seqs = [rmw.parse_attachment(a)[0] for _, a in odo]
    assert seqs == list(range(1, len(odo) + 1))  # rmw_zenoh attachment, in order
    # TF: map -> odom (+) odom -> base_link is the estimate
    for (tf, _), p in zip(got["tf"], poses, strict=True):
        mo, ob = tf.transforms
        assert (mo.header.frame_id, mo.child_frame_id) == ("map", "odom")
        assert (ob.header.frame_id, ob.child_frame_id) == ("odom", "base_link")
        pose = se2.compose(
            *[
                [
                    x.transform.translation.x,
                    x.transform.translation.y,
                    2 * math.atan2(x.transform.rotation.z, x.transform.rotation.w),
                ]
                for x in (mo, ob)
            ]
        )
        np.testing.assert_allclose(pose[:2], p[:2], atol=1e-9)
    static = got["tf_static"][0][0]
    assert {t.child_frame_id for t in static.transforms} >= {"gps_link", "imu2_link"}
    diag = got["diagnostics"][-1][0].status[0]
    values = {kv.key: kv.value for kv in diag.values}
    assert values["status"] in ("ok", "degraded") and "test_ratio/gps" in values
    assert int(values["used/gps"]) + int(values["rejected/gps"]) == 9


def test_cli_errors_are_one_line(tmp_path, bag, capsys):
    from odofuse.cli import main

    config = config_file(tmp_path, bag)
    assert main(["live", str(config.source), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("odofuse: error:") and "-o needs --replay" in err
    assert len(err.splitlines()) == 1
    p = tmp_path / "nodatum.yaml"
    p.write_text(
        CONFIG.format(bag=str(bag), estimator="ekf").replace("gps: {datum: [45.0, 9.0]}", "gps: {}")
        + "live: {transport: none}\n"
    )
    assert main(["live", str(p), "--duration", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "sensors.gps.datum" in err and "a live GPS needs a datum" in err
    p.write_text(CONFIG.format(bag=str(bag), estimator="ekf") + "live: {topics: {sonar: /s}}\n")
    assert main(["live", str(p), "--replay", str(bag)]) == 2
    assert "live.topics.sonar" in capsys.readouterr().err


def test_a_publisher_matches_only_once_a_subscription_does():
    """``wait_matched`` waits for a subscription (zenoh's MatchingStatus object is truthy
    whether or not one matches: its ``matching`` field is the answer)."""
    from odofuse.live.transport import Node, wait_matched

    node = Node(LiveOptions(listen=(), connect=(), multicast_scouting=False), name="alone")
    try:
        pub = node.publisher("/chatter", "std_msgs/msg/String", rmw.Qos())
        assert not pub.matched
        t0 = time.monotonic()
        assert not wait_matched([pub], 0.2)
        assert time.monotonic() - t0 >= 0.2  # it did wait
        node.subscribe("/chatter", "std_msgs/msg/String", rmw.Qos(), lambda *a: None)
        assert wait_matched([pub], 10.0)
    finally:
        node.close()


def test_live_mode_takes_messages_from_a_ros_publisher(tmp_path, bag):
    """``odofuse live`` without --replay: a publisher node (as a ROS 2 driver would be)
    sends the bag's JointState and Imu messages; the component steps and publishes."""
    import threading

    from odofuse.live.transport import Node, wait_matched

    port = free_port()
    live = f"{{listen: [tcp/127.0.0.1:{port}], connect: [], multicast_scouting: false}}"
    config = config_file(tmp_path, bag, live)
    comp, msgs, _ = collect(config, bag)
    result, outputs, stop = {}, [], threading.Event()

    def run():
        sink = lambda o, ty, m: outputs.append(o)  # noqa: E731
        result.update(run_live(config, duration_s=120.0, sink=sink, stop=stop))

    th = threading.Thread(target=run, daemon=True)
    th.start()
    deadline = time.monotonic() + 30.0  # until the component listens (bounded)
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            break
        except OSError:
            time.sleep(0.1)
    node = Node(
        LiveOptions(connect=(f"tcp/127.0.0.1:{port}",), listen=(), multicast_scouting=False),
        name="driver",
    )
    try:
        types = {i.topic: i.msgtype for i in comp.inputs}
        pubs = {t: node.publisher(t, ty, rmw.Qos()) for t, ty in types.items()}
        assert wait_matched(list(pubs.values()), 30.0)
        sent = 0
        for topic, _, payload, _ in msgs[:600]:
            pubs[topic].put(payload)
            sent += 1
        steps = sum(1 for topic, *_ in msgs[:600] if topic == "/joint_states") - 1
        deadline = time.monotonic() + 60.0
        while outputs.count("odometry") < steps and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:  # the live run stops whatever happened above (not after its 120 s)
        stop.set()
        th.join(timeout=30.0)
        node.close()
    assert not th.is_alive()
    assert result["handled"] == sent and result["steps"] == steps, (result, sent, steps)
    assert result["published"] == steps and result["bad"] == {}
