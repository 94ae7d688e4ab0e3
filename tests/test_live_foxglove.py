"""The Foxglove live view of ``odofuse live`` (issue 27), checked by a WebSocket client that
speaks ``foxglove.websocket.v1`` (foxglove-sdk 0.30 names it ``foxglove.sdk.v1``; RFC 6455
framing written here: no client library needed):
server info, advertise, subscribe, a binary message, its CDR decoded with rosbags."""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import json
import math
import os
import socket
import struct
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("foxglove")

from rosbag_sim import CONFIG, simulate_robot, write_robot_bag  # noqa: E402

from odofuse.config import load_config  # noqa: E402
from odofuse.live.foxglove_view import ELLIPSE_95, ellipse_points  # noqa: E402
from odofuse.live.run import Runner, prepare, replay_messages  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"  # RFC 6455 section 1.3


class WsClient:
    """A minimal WebSocket client (RFC 6455): handshake, masked text frames out, frames in."""

    def __init__(self, port: int, protocol: str, timeout: float = 10.0) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {protocol}\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(1)
            assert chunk, "connection closed during the handshake"
            head += chunk
        lines = head.decode().split("\r\n")
        assert lines[0].split()[1] == "101", lines[0]
        headers = {k.lower(): v.strip() for k, _, v in (x.partition(":") for x in lines[1:] if x)}
        accept = base64.b64encode(hashlib.sha1((key + GUID).encode()).digest()).decode()
        assert headers["sec-websocket-accept"] == accept
        self.protocol = headers.get("sec-websocket-protocol")

    def _read(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            assert chunk, "connection closed"
            out += chunk
        return out

    def recv(self) -> tuple[int, bytes]:
        """One whole message ``(opcode, payload)`` (continuation frames joined)."""
        data, opcode = b"", None
        while True:
            b0, b1 = self._read(2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._read(8))[0]
            mask = self._read(4) if b1 & 0x80 else None
            payload = self._read(n)
            if mask:
                payload = bytes(c ^ mask[i % 4] for i, c in enumerate(payload))
            op = b0 & 0x0F
            if op == 9:  # ping: answer and go on
                self.send(payload, opcode=10)
                continue
            opcode = op if op else opcode
            data += payload
            if b0 & 0x80:
                return opcode, data

    def send(self, payload: bytes, opcode: int = 1) -> None:
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 1 << 16:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        body = bytes(c ^ mask[i % 4] for i, c in enumerate(payload))
        self.sock.sendall(head + mask + body)

    def json(self, deadline: float) -> dict:
        while time.monotonic() < deadline:
            op, data = self.recv()
            if op == 1:
                return json.loads(data)
        raise AssertionError("no JSON message in time")


def test_foxglove_view_serves_the_outputs(tmp_path):
    r = simulate_robot()
    n = 301
    short = dataclasses.replace(r, t=r.t[:n], truth=r.truth[:n], wheels=r.wheels[:n])
    bag = write_robot_bag(tmp_path / "bag", dataclasses.replace(short, gyro=r.gyro[:n]), "mcap")
    p = tmp_path / "run.yaml"
    p.write_text(CONFIG.format(bag=str(bag), estimator="ekf") + "live: {transport: none}\n")
    config, log = prepare(load_config(p), str(bag))
    runner = Runner(config, log, foxglove_port=0)
    try:
        port = runner.view.port
        # foxglove-sdk 0.30 speaks the protocol under its new name foxglove.sdk.v1 (the
        # same ops as foxglove.websocket.v1, which it refuses alone): offer both
        ws = WsClient(port, "foxglove.websocket.v1, foxglove.sdk.v1")
        assert ws.protocol in ("foxglove.websocket.v1", "foxglove.sdk.v1")
        deadline = time.monotonic() + 10.0
        info = ws.json(deadline)
        assert info["op"] == "serverInfo" and info["name"] == "odofuse live"
        channels = {}
        while "/odometry/filtered" not in channels:
            msg = ws.json(deadline)
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        odo = channels["/odometry/filtered"]
        assert (odo["encoding"], odo["schemaName"]) == ("cdr", "nav_msgs/msg/Odometry")
        assert odo["schemaEncoding"] == "ros2msg" and "MSG: std_msgs/Header" in odo["schema"]
        assert {"/tf", "/tf_static", "/diagnostics", "/odofuse/covariance", "/odofuse/fix"} <= set(
            channels
        )
        # the shipped layout shows only what the view serves (and the reset topic it publishes)
        layout = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
        used = set()
        for cfg in layout["configById"].values():
            used |= set(cfg.get("topics", {}))
            used |= {p["value"].split(".")[0] for p in cfg.get("paths", [])}
            for key in ("topicToRender", "followTopic", "topicPath"):
                if key in cfg:
                    used.add(cfg[key].split(".")[0])
        assert used and used <= set(channels), used - set(channels)
        ws.send(
            json.dumps(
                {"op": "subscribe", "subscriptions": [{"id": 7, "channelId": odo["id"]}]}
            ).encode()
        )
        # the server registers the subscription: the channel then has a sink (bounded wait)
        sub_deadline = time.monotonic() + 10.0
        while not runner.view.channels["odometry"].has_sinks():
            assert time.monotonic() < sub_deadline, "the subscription was not registered"
            time.sleep(0.005)
        comp = runner.component
        msgs = replay_messages(str(bag), comp)
        for topic, _, payload, _ in msgs:
            comp.handle(topic, payload)
        pose, P = comp.loc.pose(), comp.loc.covariance()
        last = None
        deadline = time.monotonic() + 10.0
        count = 0
        while count < comp.published and time.monotonic() < deadline:
            op, data = ws.recv()
            if op != 2:
                continue
            assert data[0] == 0x01  # message data
            sub_id, log_ns = struct.unpack_from("<IQ", data, 1)
            assert sub_id == 7
            last = (log_ns, comp.ts.deserialize_cdr(data[13:], "nav_msgs/msg/Odometry"))
            count += 1
        assert count == comp.published
        ns, m = last
        assert ns == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        got = [m.pose.pose.position.x, m.pose.pose.position.y]
        np.testing.assert_array_equal(got, pose[:2])
        yaw = 2 * math.atan2(m.pose.pose.orientation.z, m.pose.pose.orientation.w)
        assert abs(yaw - pose[2]) < 1e-12
        C = np.asarray(m.pose.covariance).reshape(6, 6)[np.ix_((0, 1, 5), (0, 1, 5))]
        np.testing.assert_array_equal(C, P)
    finally:
        runner.close()


def test_ellipse_points_lie_on_the_95_percent_contour():
    P = np.array([[0.5, 0.2, 0.0], [0.2, 0.3, 0.0], [0.0, 0.0, 0.1]])
    pts = ellipse_points([1.0, 2.0, 0.0], P)
    d = pts - [1.0, 2.0]
    m = np.einsum("ni,ij,nj->n", d, np.linalg.inv(P[:2, :2]), d)
    np.testing.assert_allclose(m, ELLIPSE_95**2, rtol=1e-12)
    # chi-square(2) 95 % quantile
    assert abs(ELLIPSE_95**2 - 5.991464547107979) < 1e-12
