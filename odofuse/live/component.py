"""The live component: ROS messages in, the streaming Localizer's estimate out.

:class:`Component` is transport-free: :meth:`Component.handle` takes one message (topic, CDR
bytes) and calls ``emit(output, msgtype, message)`` for what it publishes; the command
(:mod:`odofuse.live.run`) wires ``emit`` to Zenoh publishers.

* Inputs: the configured topics (:func:`input_topics`), decoded by
  :class:`odofuse.live.messages.TopicDecoder` into ``Localizer.add_odometry`` /
  ``add_measurement`` calls. The Localizer starts at the first odometry-source message (its
  stamp is ``t0``, as the first row of a bag is ``odofuse run``'s); readings that arrive before
  it are fed right after, as the offline run feeds readings before the first step.
* Late and out-of-order readings: the Localizer's own late window (``options.<estimator>.
  late_window``) replays them; older ones are counted (``dropped_late``) and reported.
* Outputs per odometry step (at most ``live.publish_rate`` per second of message time):
  ``nav_msgs/Odometry`` (pose, covariance, the step's body twist with its covariance) and
  ``/tf`` (``odom -> base_link`` = the Localizer's continuous odometry pose, ``map -> odom`` =
  the correction, REP-105); ``/tf_static`` once (the sensor mounts, transient local);
  ``diagnostic_msgs/DiagnosticArray`` every ``live.diagnostics_period`` seconds.
* Health: the Localizer's status and findings, per-sensor test ratios, sensor timeouts
  (:func:`live_health`) and the counts of skipped messages by reason.
* Reset: a ``geometry_msgs/PoseWithCovarianceStamped`` on the reset topic (robot_localization's
  ``set_pose``) restarts the Localizer at the next odometry message from that pose, exactly as
  a fresh start with ``initial.pose`` would.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from odofuse import se2
from odofuse.declarations.live import DEFAULT_OUTPUTS, DEFAULT_TOPICS, INPUT_KINDS
from odofuse.errors import ConfigError, InputError
from odofuse.io.bags import stream_name
from odofuse.live import messages
from odofuse.live.messages import BadMessage
from odofuse.options import explicit
from odofuse.status.findings import Finding, status_of

RESET_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
TF_TYPE = "tf2_msgs/msg/TFMessage"
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
#: Output name -> message type.
OUTPUT_TYPES = {
    "odometry": ODOMETRY_TYPE,
    "tf": TF_TYPE,
    "tf_static": TF_TYPE,
    "diagnostics": DIAGNOSTICS_TYPE,
}


@dataclass(frozen=True)
class InputTopic:
    topic: str
    kind: str  # an INPUT_KINDS key
    k: int  # the k-th topic of its kind (0-based): streams gyro, gyro_2, ...

    @property
    def msgtype(self) -> str:
        return INPUT_KINDS[self.kind]


@dataclass(frozen=True)
class LiveHealth:
    """What the diagnostics carry: status, findings and per-sensor test ratios.

    ``test_ratios``: the last reading's NIS over its gate threshold per stream (> 1: the gate
    rejected it), as robot_localization's and PX4's innovation test ratios.
    """

    status: str
    findings: tuple
    test_ratios: dict


def live_health(loc, extra_findings=()) -> LiveHealth:
    """The adapter from what the Localizer offers to :class:`LiveHealth`.

    ``Localizer.health()`` gives status and findings; the test ratios are read from its
    monitor's last NIS per stream and gate (the one place this package reads the monitor).
    When ``Localizer.health()`` returns the test ratios itself, only this function changes.
    """
    h = loc.health()
    mon = loc.monitor
    ratios = {}
    for s, nis in mon._nis.items():
        gate = mon.gates.get(s)
        if len(nis) and gate is not None and math.isfinite(gate) and gate > 0:
            ratios[s] = float(nis[-1]) / float(gate)
    findings = tuple(h.findings) + tuple(extra_findings)
    return LiveHealth(status_of(findings), findings, ratios)


def input_topics(config, log=None) -> list[InputTopic]:
    """The topics to subscribe: ``live.topics``, else ``log.topics``, else the bag's topic of
    each needed type (``log.ros["topics"]`` when the bag reader recorded it), else the defaults
    (:data:`odofuse.declarations.live.DEFAULT_TOPICS`). Only the kinds the config uses: the
    drive's odometry source and the sensor blocks' streams."""
    from odofuse.estimators.common import odometry_stream_name
    from odofuse.motion import motion_model_from_config

    live, src = config.live, config.source
    given = dict(live.topics or config.log_options.get("topics") or {})
    for kind in given:
        if kind not in INPUT_KINDS:
            raise ConfigError(
                f"unknown input kind '{kind}' (known: {', '.join(INPUT_KINDS)})",
                src,
                f"live.topics.{kind}",
            )
    source = odometry_stream_name(motion_model_from_config(config))
    source_kind = {"wheels": "wheels", "odometry": "odometry", "cmd_vel": "twist"}[source]
    needed = {source_kind}
    for s in config.sensors:
        base = s.rsplit("_", 1)[0] if s[-1].isdigit() and "_" in s else s
        if base in ("gyro", "compass"):
            needed.add("gyro")
        elif base == "gps":
            needed.add("gps")
    out = []
    for kind in INPUT_KINDS:
        if kind not in needed:
            continue
        wanted = given.get(kind, DEFAULT_TOPICS[kind])
        for k, topic in enumerate([wanted] if isinstance(wanted, str) else list(wanted)):
            out.append(InputTopic(str(topic), kind, k))
    return out


class Component:
    """The streaming Localizer behind ROS messages (see the module doc).

    Parameters
    ----------
    config : RunConfig
        After :func:`odofuse.log_defaults.apply_log_defaults` when a bag supplies defaults.
    emit : callable
        ``emit(output, msgtype, message)``, ``output`` one of :data:`OUTPUT_TYPES`, or
        ``"fix"`` with a GPS reading's row (for the Foxglove view only).
    log : SensorLog, optional
        The bag (replay, or the config's ``log:`` for defaults): landmarks, start pose,
        base frame, sensor frames and mounts.
    keep_trajectory : bool
        Keep every pose (a replay that writes the output folder).
    estimator : str, optional
        ``ekf``, ``ukf`` or ``particle`` (default ``config.estimator``).
    """

    def __init__(
        self,
        config,
        emit: Callable,
        log=None,
        keep_trajectory: bool = False,
        estimator: str | None = None,
    ) -> None:
        from odofuse.live import rmw

        self.config = config
        self.live = config.live
        self.emit = emit
        self.estimator = estimator or config.estimator
        if self.estimator not in ("ekf", "ukf", "particle"):
            raise ConfigError(
                f"odofuse live streams ekf, ukf or particle, not '{self.estimator}'",
                config.source,
                "estimator",
            )
        self.keep_trajectory = keep_trajectory
        self.log = log
        ros = (getattr(log, "ros", None) or {}) if log is not None else {}
        self.ros = ros
        self.ts = rmw.typestore(self.live.distro)
        self.T = self.ts.types
        self.map_frame = self.live.map_frame
        self.odom_frame = self.live.odom_frame
        self.base_frame = self.live.base_frame or ros.get("base_frame") or "base_link"
        self.outputs = {**DEFAULT_OUTPUTS, **dict(self.live.outputs or {})}
        for name in self.outputs:
            if name not in DEFAULT_OUTPUTS:
                raise ConfigError(
                    f"unknown output '{name}' (known: {', '.join(DEFAULT_OUTPUTS)})",
                    config.source,
                    f"live.outputs.{name}",
                )
        self.inputs = input_topics(config, log)
        self.loc = None
        self._probe = self._new_localizer(0.0)  # the streams it uses; config errors now
        # one step now, so that the first live step does not pay for loading the kernels
        self._probe.add_odometry(1e-3, np.zeros(len(self._probe.motion_model.drive.input_names)))
        self.decoders = {i.topic: self._decoder(i) for i in self.inputs}
        self._early: list = []  # readings before the Localizer starts
        self._reset: tuple | None = None
        self.bad: dict[str, int] = {}
        self.bad_last: str = ""
        self.last_seen: dict[str, float] = {}
        self.timeouts_raised: dict[str, int] = {}
        self._timed_out: set[str] = set()
        self.t_now: float | None = None
        self.t_start: float | None = None
        self._t_pub = -math.inf
        self._t_diag = -math.inf
        self.steps = 0
        self.published = 0

    # ----------------------------------------------------------------- setup
    def _new_localizer(self, t0: float, initial=None):
        from odofuse.estimators.localizer import Localizer

        config = self.config
        if initial is not None:
            pose, cov = initial
            sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            if not np.any(sigma):
                sigma = np.asarray(config.initial.sigma, dtype=float)
            init = dataclasses.replace(
                config.initial, pose=tuple(map(float, pose)), sigma=tuple(map(float, sigma))
            )
            config = dataclasses.replace(config, initial=init)
        log = self.log
        return Localizer.from_config(
            config,
            t0,
            landmarks=getattr(log, "landmarks", None),
            initial_pose=getattr(log, "initial_pose", None),
            estimator=self.estimator,
            keep_trajectory=self.keep_trajectory,
        )

    def _decoder(self, inp: InputTopic) -> messages.TopicDecoder:
        loc = self._probe
        known = set(loc.models) | ({loc._gyro_stream} - {None})
        streams = {}
        if inp.kind == "gyro":
            for key, kind in (("main", "gyro"), ("compass", "compass")):
                name = stream_name(kind, inp.k)
                if name in known:
                    streams[key] = name
        elif inp.kind == "gps":
            name = stream_name("gps", inp.k)
            if name in known:
                streams["main"] = name
        main = streams.get("main", streams.get("compass"))
        mounts = self.ros.get("mounts", {})
        frames = self.ros.get("frames", {})
        yaw = float(mounts.get(stream_name("gyro", inp.k), [0.0, 0.0, 0.0])[2])
        drop = frozenset(
            s for s, b in self.config.sensors.items() if "sigma" in explicit(b) and s in known
        )
        drive = loc.motion_model.drive
        joints = self.live.joints or self.config.log_options.get("joints")
        return messages.TopicDecoder(
            topic=inp.topic,
            kind=inp.kind,
            streams=streams,
            drive_inputs=tuple(drive.input_names),
            drive_kinds=tuple(getattr(drive, "input_kinds", ())),
            joints=dict(joints) if joints else None,
            yaw_offset=yaw if inp.kind == "gyro" else 0.0,
            frame=frames.get(main) if main and frames.get(main) else None,
            drop_sigma=drop,
        )

    def static_transforms(self) -> list:
        """``base -> sensor frame`` of every mount the bag's /tf_static or a GPS lever arm gave."""
        out, seen = [], set()
        mounts, frames = self.ros.get("mounts", {}), self.ros.get("frames", {})
        for stream, mount in mounts.items():
            frame = frames.get(stream)
            if frame and frame not in seen:
                seen.add(frame)
                out.append((frame, [float(mount[0]), float(mount[1]), float(mount[2])]))
        for s, block in self.config.sensors.items():
            arm = getattr(block, "lever_arm", None)
            frame = frames.get(s) or f"{s}_link"
            if arm is not None and frame not in seen:
                seen.add(frame)
                out.append((frame, [float(arm[0]), float(arm[1]), 0.0]))
        return out

    def start(self) -> None:
        """Publish ``/tf_static`` (once: it is transient local)."""
        T = self.T
        tfs = [
            messages.transform(T, 0.0, self.base_frame, f, p) for f, p in self.static_transforms()
        ]
        self.emit("tf_static", TF_TYPE, messages.tf_msg(T, tfs))

    # ----------------------------------------------------------------- input
    def count_bad(self, reason: str, detail: str) -> None:
        self.bad[reason] = self.bad.get(reason, 0) + 1
        self.bad_last = detail[:200]

    def handle(self, topic: str, payload: bytes) -> None:
        """One message from the transport; never raises on bad input (it is counted)."""
        if topic == self.outputs["reset"]:
            try:
                self.reset(*messages.reset_pose(self.ts.deserialize_cdr(payload, RESET_TYPE)))
            except BadMessage as exc:
                self.count_bad(exc.reason, str(exc))
            except Exception as exc:  # a payload that is not CDR of the type
                self.count_bad("undecodable", f"{topic}: {exc}")
            return
        dec = self.decoders.get(topic)
        if dec is None:
            return
        try:
            msg = self.ts.deserialize_cdr(payload, INPUT_KINDS[dec.kind])
        except Exception as exc:
            self.count_bad("undecodable", f"{topic}: {exc}")
            return
        try:
            readings = dec.decode(msg)
        except BadMessage as exc:
            self.count_bad(exc.reason, str(exc))
            return
        for r in readings:
            self.feed(r)

    def feed(self, r: messages.Reading) -> None:
        """One reading (decoded message) into the Localizer."""
        t = float(r.t)
        if r.kind == "start":
            if self.loc is None:
                self._begin(t)
            self._seen("__odometry__", t)
            return
        if self.loc is None:
            self._early.append(r)
            return
        try:
            if r.kind == "odometry":
                self.loc.add_odometry(t, r.u)
                self._seen("__odometry__", t)
                self.steps += 1
                self._after_step(t, r.u)
            else:
                self.loc.add_measurement(r.stream, r.row)
                self._seen(r.stream, t)
                if "lat" in r.row:  # a raw GPS fix, for the live view (not a ROS output)
                    self.emit("fix", "", r.row)
        except InputError as exc:
            reason = "time_backwards" if "before the filter time" in str(exc) else "invalid"
            self.count_bad(reason, str(exc))

    def _begin(self, t0: float) -> None:
        initial = self._reset[1:] if self._reset is not None else None
        self.loc = self._new_localizer(t0, initial)
        self._reset = None
        if self.t_start is None:
            self.t_start = t0
        early, self._early = self._early, []
        for r in early:
            self.feed(r)

    def reset(self, t: float, pose, cov) -> None:
        """Restart from ``pose`` at the next odometry message (a fresh start)."""
        self.loc = None
        self._reset = (t, np.asarray(pose, dtype=float), np.asarray(cov, dtype=float))
        self._early = []
        for d in self.decoders.values():
            if d.kind in ("wheels", "odometry", "twist"):
                d._prev = None

    # ----------------------------------------------------------------- health
    def _seen(self, stream: str, t: float) -> None:
        self.last_seen[stream] = max(t, self.last_seen.get(stream, -math.inf))
        if self.t_now is None or t > self.t_now:
            self.t_now = t
        if stream in self._timed_out:
            self._timed_out.discard(stream)
        self._check_timeouts()

    def timeout_of(self, stream: str) -> float:
        return float(dict(self.live.timeouts or {}).get(stream, self.live.timeout))

    def watched(self) -> list[str]:
        loc = self._probe
        return ["__odometry__", *[s for s in loc.models if s in self._fed_streams()]]

    def _fed_streams(self) -> set[str]:
        return {s for d in self.decoders.values() for s in d.streams.values()}

    def timeout_findings(self) -> list[Finding]:
        """A finding per watched stream silent longer than its timeout (message time)."""
        out = []
        if self.t_now is None:
            return out
        for s in self.watched():
            last = self.last_seen.get(s, self.t_start)
            if last is None:
                continue
            gap = self.t_now - last
            if gap > self.timeout_of(s):
                name = "odometry" if s == "__odometry__" else s
                out.append(
                    Finding(
                        "timeout",
                        f"no reading for {gap:.2f} s (timeout {self.timeout_of(s):g} s)",
                        sensor=name,
                        t_start=float(last),
                        t_end=float(self.t_now),
                        figure=float(gap),
                    )
                )
        return out

    def _check_timeouts(self) -> None:
        for f in self.timeout_findings():
            s = "__odometry__" if f.sensor == "odometry" else f.sensor
            if s not in self._timed_out:
                self._timed_out.add(s)
                self.timeouts_raised[f.sensor] = self.timeouts_raised.get(f.sensor, 0) + 1

    def health(self) -> LiveHealth:
        if self.loc is None:
            return LiveHealth("degraded", (Finding("waiting", "no odometry yet"),), {})
        return live_health(self.loc, self.timeout_findings())

    # ----------------------------------------------------------------- output
    def _twist(self, u, dt: float):
        """Body twist ``[vx, vy, omega]`` of the step and its covariance (3, 3)."""
        if not dt > 0:
            return np.zeros(3), np.zeros((3, 3))
        mm = self.loc.motion_model
        delta, J = mm.increment(np.asarray(u, dtype=float))
        cov = J @ mm.input_cov(np.asarray(u, dtype=float)) @ J.T
        return np.asarray(delta) / dt, cov / dt**2

    def _after_step(self, t: float, u) -> None:
        rate = self.live.publish_rate
        if rate <= 0 or t - self._t_pub >= 1.0 / rate - 1e-9:
            dt = t - self._last_step_t if getattr(self, "_last_step_t", None) is not None else 0
            self.publish_estimate(t, u, dt)
            self._t_pub = t
        self._last_step_t = t
        if t - self._t_diag >= self.live.diagnostics_period:
            self.publish_diagnostics(t)
            self._t_diag = t

    def publish_estimate(self, t: float, u, dt: float) -> None:
        loc, T = self.loc, self.T
        twist, twist_cov = self._twist(u, dt)
        odo = messages.odometry_msg(
            T, t, loc.pose(), loc.covariance(), twist, twist_cov, self.map_frame, self.base_frame
        )
        self.emit("odometry", ODOMETRY_TYPE, odo)
        tf = messages.tf_msg(
            T,
            [
                messages.transform(T, t, self.map_frame, self.odom_frame, loc.map_to_odom()),
                messages.transform(T, t, self.odom_frame, self.base_frame, loc.odom_pose()),
            ],
        )
        self.emit("tf", TF_TYPE, tf)
        self.published += 1

    def diagnostic_values(self, h: LiveHealth) -> list[tuple[str, str]]:
        loc = self.loc
        vals = [("status", h.status), ("estimator", self.estimator), ("steps", self.steps)]
        if loc is not None:
            p = loc.pose()
            vals += [("x", f"{p[0]:.4f}"), ("y", f"{p[1]:.4f}"), ("theta", f"{p[2]:.5f}")]
            for s in loc.models:
                vals.append((f"used/{s}", loc.used[s]))
                vals.append((f"rejected/{s}", loc.rejected[s]))
                if loc.dropped_late.get(s):
                    vals.append((f"dropped_late/{s}", loc.dropped_late[s]))
        for s, r in sorted(h.test_ratios.items()):
            vals.append((f"test_ratio/{s}", f"{r:.4f}"))
        for reason, n in sorted(self.bad.items()):
            vals.append((f"bad/{reason}", n))
        if self.bad:  # what the last skipped message was, for the operator (topic, field, why)
            vals.append(("bad/last", self.bad_last))
        for s, n in sorted(self.timeouts_raised.items()):
            vals.append((f"timeouts/{s}", n))
        for i, f in enumerate(h.findings):
            vals.append((f"finding/{i}", f.line()))
        return vals

    def publish_diagnostics(self, t: float) -> None:
        h = self.health()
        level = messages.LEVEL_OK if h.status == "ok" else messages.LEVEL_WARN
        text = h.status if not h.findings else f"{h.status}: {h.findings[0].line()}"
        msg = messages.diagnostics_msg(
            self.T,
            t,
            f"{self.live.node}: localizer",
            self.base_frame,
            level,
            text[:300],
            self.diagnostic_values(h),
        )
        self.emit("diagnostics", DIAGNOSTICS_TYPE, msg)

    def finish(self):
        """Count what still waits for odometry; the Localizer's result (None before a start)."""
        if self.loc is None:
            return None
        self.loc.finish()
        return self.loc.result()


def map_odom_correction(prev_pose, post_pose, inc) -> np.ndarray:
    """``C = post (+) pred^-1`` with ``pred = prev (+) inc``: the rigid map-frame correction a
    step's updates applied (``map -> odom`` moves by exactly this, REP-105)."""
    pred = se2.compose(prev_pose, inc)
    return se2.compose(post_pose, se2.inverse(pred))
