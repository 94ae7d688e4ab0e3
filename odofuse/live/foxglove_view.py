"""The live view in Foxglove: ``odofuse live CONFIG --foxglove [PORT]``.

A ``foxglove-sdk`` WebSocket server (protocol ``foxglove.websocket.v1``, on 127.0.0.1 by
default) that Foxglove opens directly ("Open connection" -> ``ws://localhost:8765``; the layout
``docs/foxglove-layout.json`` arranges it). Channels:

* the component's outputs, as on the ROS 2 topics: ``/odometry/filtered``, ``/tf``,
  ``/tf_static``, ``/diagnostics``, CDR with their ``ros2msg`` schemas (the message definitions
  of the configured distribution, as rosbag2's MCAP files carry them);
* ``/odofuse/covariance`` (``foxglove.SceneUpdate``): the 95 % position ellipse of the
  estimate in the map frame;
* ``/odofuse/fix`` (``foxglove.LocationFix``): every raw GPS fix the component received;
* ``/odofuse/landmarks`` (``foxglove.SceneUpdate``): the known landmark/beacon map, once.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse.live.component import OUTPUT_TYPES

#: sqrt of the chi-square 95 % quantile with 2 degrees of freedom (the ellipse's scale).
ELLIPSE_95 = math.sqrt(-2.0 * math.log(0.05))
#: Points on the ellipse outline.
ELLIPSE_POINTS = 48


def ellipse_points(pose, P, scale: float = ELLIPSE_95, n: int = ELLIPSE_POINTS) -> np.ndarray:
    """``(n, 2)`` outline of the position ellipse ``{d : d^T P_xy^-1 d = scale^2}`` about
    ``pose[:2]`` (world frame)."""
    w, V = np.linalg.eigh(0.5 * (P[:2, :2] + P[:2, :2].T))
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    unit = np.column_stack([np.cos(a), np.sin(a)])
    return np.asarray(pose[:2]) + scale * (unit * np.sqrt(np.clip(w, 0.0, None))) @ V.T


class FoxgloveView:
    """The Foxglove WebSocket server of one component (see the module doc)."""

    def __init__(self, component, port: int = 8765, host: str = "127.0.0.1") -> None:
        import foxglove
        from foxglove.channels import LocationFixChannel, SceneUpdateChannel

        self.component = component
        self.context = foxglove.Context()
        ts = component.ts
        self.channels = {}
        for name, ty in OUTPUT_TYPES.items():
            text, _ = ts.generate_msgdef(ty, ros_version=2)
            schema = foxglove.Schema(name=ty, encoding="ros2msg", data=text.encode())
            self.channels[name] = foxglove.Channel(
                component.outputs[name],
                schema=schema,
                message_encoding="cdr",
                context=self.context,
            )
        self.ellipse = SceneUpdateChannel("/odofuse/covariance", context=self.context)
        self.fix = LocationFixChannel("/odofuse/fix", context=self.context)
        self.landmarks = SceneUpdateChannel("/odofuse/landmarks", context=self.context)
        self.server = foxglove.start_server(
            name="odofuse live", host=host, port=port, context=self.context
        )
        self.port = self.server.port

    def log(self, output: str, msgtype: str, msg, data: bytes | None) -> None:
        """One output of the component (``emit``'s arguments, ``data`` its CDR or None)."""
        if output == "fix":
            self._fix(msg)
            return
        ch = self.channels.get(output)
        if ch is None:
            return
        stamp = getattr(getattr(msg, "header", None), "stamp", None)
        ns = None if stamp is None else stamp.sec * 10**9 + stamp.nanosec
        if output in ("tf", "tf_static") and msg.transforms:
            st = msg.transforms[0].header.stamp
            ns = st.sec * 10**9 + st.nanosec
        payload = data if data is not None else self.component.ts.serialize_cdr(msg, msgtype)
        ch.log(bytes(payload), log_time=ns)
        if output == "odometry":
            self._ellipse(msg, ns)

    def _ellipse(self, msg, ns) -> None:
        from foxglove.messages import (
            Color,
            LinePrimitive,
            LinePrimitiveLineType,
            Point3,
            SceneEntity,
            SceneUpdate,
            Timestamp,
        )

        p = msg.pose.pose
        pose = [p.position.x, p.position.y]
        C = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
        pts = ellipse_points(pose, C)
        stamp = Timestamp(sec=ns // 10**9, nsec=ns % 10**9)
        line = LinePrimitive(
            type=LinePrimitiveLineType.LineLoop,
            thickness=0.03,
            points=[Point3(x=float(x), y=float(y), z=0.0) for x, y in pts],
            color=Color(r=1.0, g=0.5, b=0.0, a=1.0),
        )
        entity = SceneEntity(timestamp=stamp, frame_id=msg.header.frame_id, id="p95", lines=[line])
        self.ellipse.log(SceneUpdate(entities=[entity]), log_time=ns)

    def _fix(self, row: dict) -> None:
        from foxglove.messages import LocationFix, Timestamp

        if "lat" not in row:
            return
        ns = int(round(row["t"] * 1e9))
        sigma = row.get("sigma")
        cov = [0.0] * 9 if sigma is None else [sigma**2, 0, 0, 0, sigma**2, 0, 0, 0, 0]
        msg = LocationFix(
            timestamp=Timestamp(sec=ns // 10**9, nsec=ns % 10**9),
            frame_id="gps",
            latitude=float(row["lat"]),
            longitude=float(row["lon"]),
            altitude=0.0,
            position_covariance=[float(c) for c in cov],
        )
        self.fix.log(msg, log_time=ns)

    def log_landmarks(self, landmarks: dict, frame: str) -> None:
        """The landmark map, once (spheres at the known positions)."""
        from foxglove.messages import (
            Color,
            Pose,
            Quaternion,
            SceneEntity,
            SceneUpdate,
            SpherePrimitive,
            Vector3,
        )

        spheres = [
            SpherePrimitive(
                pose=Pose(
                    position=Vector3(x=float(p[0]), y=float(p[1]), z=0.0),
                    orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                ),
                size=Vector3(x=0.3, y=0.3, z=0.3),
                color=Color(r=0.2, g=0.6, b=1.0, a=1.0),
            )
            for p in landmarks.values()
        ]
        if spheres:
            entity = SceneEntity(frame_id=frame, id="landmarks", spheres=spheres)
            self.landmarks.log(SceneUpdate(entities=[entity]))

    def close(self) -> None:
        self.server.stop()
