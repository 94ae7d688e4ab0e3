"""``odofuse live CONFIG [--replay BAG [--rate R] [-o OUT]] [--foxglove [PORT]]``.

Live: a ROS 2 node ``odofuse`` on Zenoh (:mod:`odofuse.live.transport`) subscribes to the
configured topics and publishes the estimate (:mod:`odofuse.live.component`) until
interrupted (or ``duration_s``).

Replay: the bag's input messages are published by a second node (``odofuse_player``) on the
same transport into the same component, as fast as it takes them without dropping one
(reliable, blocking congestion control) or at ``--rate`` times real time. Messages of equal
stamp go out in the order ``odofuse run`` applies them (measurements before the odometry step
ending there, in the config's sensor order), so that with ``-o`` the output folder is the one
``odofuse run`` writes, the trajectory equal to the last digit. The replay waits (at most
:data:`MATCH_WAIT_S`) for its subscriptions to match before it starts.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from pathlib import Path

from odofuse.errors import ConfigError, InputError
from odofuse.live import rmw
from odofuse.live.component import OUTPUT_TYPES, RESET_TYPE, Component

#: Longest wait for publishers to match their subscriptions before a replay starts (s).
MATCH_WAIT_S = 5.0
#: A replay ends when every published message was handled, or after this long without one (s).
IDLE_END_S = 10.0


def prepare(config, bag: str | None):
    """``(config, log)`` the component runs on: the bag's defaults applied (replay: ``bag``;
    live: the config's ``log:`` when it is a readable bag), else the config as it is."""
    from odofuse.io.loader import load_log_for
    from odofuse.log_defaults import apply_log_defaults

    if bag is not None:
        config = dataclasses.replace(config, log=str(bag))
    else:  # checked before a bag's first fix could stand in for it
        for s, block in config.sensors.items():
            if getattr(block, "datum", "absent") is None:
                raise ConfigError(
                    "a live GPS needs a datum (the first fix of a live stream is not known "
                    "in advance)",
                    config.source,
                    f"sensors.{s}.datum",
                )
    try:
        log = load_log_for(config)
    except (InputError, OSError):
        if bag is not None:
            raise
        log = None
    if log is not None and getattr(log, "ros", None):
        config, log = apply_log_defaults(config, log)
    elif log is not None:
        log = None  # a CSV folder or dataset: nothing a live node can take from it
    return config, log


def replay_messages(bag, component: Component):
    """``[(topic, msgtype, cdr bytes, stamp)]`` of the bag's inputs, in ``odofuse run``'s order."""
    from rosbags.highlevel import AnyReader

    from odofuse.io import ros_msgs

    topics = {i.topic: i for i in component.inputs}
    ranks = {s: k for k, s in enumerate(component.config.sensors)}
    path = Path(bag)
    if path.is_file() and (path.parent / "metadata.yaml").exists():
        path = path.parent
    out = []
    with AnyReader([path], default_typestore=component.ts) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, bag_ns, data in reader.messages(connections=conns):
            inp = topics[conn.topic]
            msg = reader.deserialize(data, conn.msgtype)
            t = ros_msgs.stamp(msg, bag_ns)
            dec = component.decoders[conn.topic]
            odo = inp.kind in ("wheels", "odometry", "twist")
            rank = min((ranks.get(s, len(ranks)) for s in dec.streams.values()), default=0)
            payload = component.ts.serialize_cdr(msg, inp.msgtype)
            out.append(((t, 1 if odo else 0, rank, len(out)), conn.topic, inp.msgtype, payload))
    out.sort(key=lambda e: e[0])
    return [(topic, ty, payload, key[0]) for key, topic, ty, payload in out]


class Runner:
    """The component on a Zenoh node, its inbox and its outputs."""

    def __init__(self, config, log=None, keep_trajectory=False, foxglove_port=None, sink=None):
        from odofuse.live.transport import Node

        self.inbox: queue.Queue = queue.Queue()
        self.sink = sink
        self.view = None
        self.node = None
        self.pubs = {}
        self.component = Component(config, self.emit, log, keep_trajectory)
        live = config.live
        if foxglove_port is not None:
            from odofuse.live.foxglove_view import FoxgloveView

            self.view = FoxgloveView(self.component, foxglove_port)
            self.view.log_landmarks(getattr(log, "landmarks", None) or {}, live.map_frame)
        if live.transport == "zenoh":
            self.node = Node(live, config.source)
            data_qos = rmw.Qos(reliable=live.reliable, depth=live.depth)
            for name, ty in OUTPUT_TYPES.items():
                q = rmw.Qos(reliable=True, transient_local=True, depth=1)
                self.pubs[name] = self.node.publisher(
                    self.component.outputs[name], ty, q if name == "tf_static" else data_qos
                )
            for inp in self.component.inputs:
                self.node.subscribe(inp.topic, inp.msgtype, data_qos, self._receive)
            self.node.subscribe(
                self.component.outputs["reset"], RESET_TYPE, data_qos, self._receive
            )
        self.handled = 0

    def _receive(self, topic, payload, arrival_ns, attachment=None) -> None:
        self.inbox.put((topic, payload, arrival_ns, attachment))

    def sequence(self, messages_) -> None:
        """Replay: hand messages to the component in the player's order. Zenoh keeps each
        publisher's samples in order but not the order across topics; the attachment's
        sequence number (per publisher, from 1) gives each sample's place in the replay."""
        counts: dict[str, int] = {}
        self._order = {}
        for i, (topic, *_rest) in enumerate(messages_):
            counts[topic] = counts.get(topic, 0) + 1
            self._order[(topic, counts[topic])] = i
        self._held, self._next = {}, 0

    def emit(self, output: str, msgtype: str, msg) -> None:
        data = None
        if output in self.pubs:
            data = self.component.ts.serialize_cdr(msg, msgtype)
            self.pubs[output].put(data)
        if self.view is not None:
            self.view.log(output, msgtype, msg, data)
        if self.sink is not None:
            self.sink(output, msgtype, msg)

    def step(self, timeout_s: float) -> bool:
        """Handle one inbox message (waiting at most ``timeout_s``); False when none came."""
        try:
            topic, payload, _, att = self.inbox.get(timeout=timeout_s)
        except queue.Empty:
            return False
        order = getattr(self, "_order", None)
        index = None
        if order is not None and att is not None and topic in self._topics_of_replay():
            index = order.get((topic, rmw.parse_attachment(att)[0]))
        if index is None:  # live, or a sample that is not the player's
            self.component.handle(topic, payload)
            self.handled += 1
            return True
        self._held[index] = (topic, payload)
        while self._next in self._held:
            self.component.handle(*self._held.pop(self._next))
            self._next += 1
            self.handled += 1
        return True

    def _topics_of_replay(self) -> set:
        if not hasattr(self, "_replay_topics"):
            self._replay_topics = {t for t, _ in self._order}
        return self._replay_topics

    def flush(self) -> None:
        """Replay end (a sample lost or late): the held samples in their order."""
        for index in sorted(getattr(self, "_held", {})):
            self.component.handle(*self._held.pop(index))
            self.handled += 1

    def close(self) -> None:
        if self.view is not None:
            self.view.close()
        if self.node is not None:
            self.node.close()


def play(runner: Runner, messages_, rate: float | None, live) -> threading.Thread:
    """Publish ``messages_`` from a player node (a thread); returns the thread."""
    from odofuse.live.transport import Node, wait_matched

    # the player reaches the component where it listens, else through the same router
    connect = tuple(live.listen) if live.listen else live.connect
    player = Node(
        dataclasses.replace(live, listen=(), connect=connect, node="odofuse_player"),
        name="odofuse_player",
    )
    qos = rmw.Qos(reliable=True, depth=live.depth)
    pubs = {}
    for topic, ty, _, _ in messages_:
        if topic not in pubs:
            pubs[topic] = player.publisher(topic, ty, qos)
    wait_matched(list(pubs.values()), MATCH_WAIT_S)

    def run():
        try:
            t_first, w_first = (messages_[0][3] if messages_ else 0.0), time.monotonic()
            for topic, _, payload, t in messages_:
                if rate:
                    delay = (t - t_first) / rate - (time.monotonic() - w_first)
                    if delay > 0:
                        time.sleep(delay)
                pubs[topic].put(payload)
        finally:
            time.sleep(0.2)  # let the last samples leave before the session closes
            player.close()

    th = threading.Thread(target=run, name="odofuse-player", daemon=True)
    th.start()
    return th


def run_live(
    config,
    replay: str | None = None,
    rate: float | None = None,
    out: str | None = None,
    foxglove_port: int | None = None,
    duration_s: float | None = None,
    sink=None,
    stop=None,
) -> dict:
    """The ``odofuse live`` command; returns a summary (and writes ``out`` after a replay).

    A live run ends after ``duration_s`` or when ``stop`` (a ``threading.Event``) is set;
    ``sink(output, msgtype, message)`` sees every output (an embedding program's hook)."""
    from odofuse.io.atomic import claim_folder

    if out is not None and replay is None:
        raise ConfigError("-o needs --replay (a live run has no end to write)", config.source)
    if rate is not None and not rate > 0:
        raise ConfigError(f"--rate must be > 0, got {rate}", config.source)
    config, log = prepare(config, replay)
    runner = Runner(config, log, keep_trajectory=out is not None, sink=sink)
    comp = runner.component
    t0 = time.perf_counter()
    try:
        if runner.node is not None:
            from odofuse.live.transport import wait_matched

            wait_matched([runner.pubs["odometry"]], 2.0 if replay else 0.0)
        comp.start()
        if replay is not None:
            msgs = replay_messages(replay, comp)
            if runner.node is None:  # transport none: straight into the component
                for topic, _, payload, _ in msgs:
                    comp.handle(topic, payload)
                    runner.handled += 1
            else:
                runner.sequence(msgs)
                th = play(runner, msgs, rate, config.live)
                idle = time.monotonic()
                while runner.handled < len(msgs):
                    if runner.step(0.1):
                        idle = time.monotonic()
                    elif time.monotonic() - idle > IDLE_END_S:
                        break
                th.join(timeout=IDLE_END_S)
                runner.flush()
        else:
            end = None if duration_s is None else time.monotonic() + duration_s
            while (end is None or time.monotonic() < end) and not (stop and stop.is_set()):
                runner.step(0.1)
            for _ in range(runner.inbox.qsize()):  # what had arrived by the end
                runner.step(0.0)
        if comp.loc is not None:
            comp.publish_diagnostics(comp.t_now if comp.t_now is not None else 0.0)
        runtime = time.perf_counter() - t0
        result = comp.finish()
        summary = {
            "handled": runner.handled,
            "steps": comp.steps,
            "published": comp.published,
            "bad": dict(comp.bad),
            "status": comp.health().status if comp.loc is not None else "degraded",
        }
        if replay is not None:
            summary["messages"] = len(msgs)
        if out is not None:
            if result is None:
                raise InputError("the replay gave no odometry: nothing to write", replay)
            from odofuse.rundir import finish_run

            with claim_folder(Path(out)):
                summary["metrics"] = finish_run(config, log, result, runtime, Path(out))
        return summary
    finally:
        runner.close()
