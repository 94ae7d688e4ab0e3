"""A ROS 2 node on Zenoh in rmw_zenoh's wire format (:mod:`odofuse.live.rmw`): one session,
its liveliness tokens, publishers that attach rmw_zenoh's attachment, subscriptions that hand
``(topic, CDR bytes, arrival time)`` to a callback.

Transient-local endpoints (``/tf_static``) use zenoh-ext's advanced publisher (a cache of the
last ``depth`` samples, publisher detection) and advanced subscriber (history of late-joining
publishers), as rmw_zenoh does for ``TRANSIENT_LOCAL`` durability.
"""

from __future__ import annotations

import hashlib
import itertools
import time

from odofuse.live import rmw


class Node:
    """One ROS 2 node: a Zenoh session with its ``NN`` token and its endpoints.

    Parameters
    ----------
    live : odofuse.declarations.live.LiveOptions
        Session (mode, endpoints, scouting), domain, distro, node name and namespace.
    source : str
        The config file, for error messages.
    name : str, optional
        Node name (default ``live.node``).
    """

    def __init__(self, live, source: str = "<config>", name: str | None = None) -> None:
        import zenoh

        self.live = live
        self.distro = live.distro
        self.domain = rmw.domain_id(live.domain_id, source)
        self.name = name or live.node
        self.namespace = live.namespace
        self.session = zenoh.open(rmw.session_config(live, source))
        self.zid = str(self.session.zid())
        self._ids = itertools.count(1)
        self.node_id = 0
        self._tokens = [
            self.session.liveliness().declare_token(
                rmw.node_token(self.domain, self.zid, self.node_id, self.namespace, self.name)
            )
        ]
        self._endpoints: list = []

    def _token(self, kind: str, topic: str, msgtype: str, qos: rmw.Qos) -> int:
        eid = next(self._ids)
        key = rmw.entity_token(
            self.domain,
            self.zid,
            self.node_id,
            eid,
            kind,
            self.namespace,
            self.name,
            topic,
            msgtype,
            self.distro,
            qos,
        )
        self._tokens.append(self.session.liveliness().declare_token(key))
        return eid

    def keyexpr(self, topic: str, msgtype: str) -> str:
        return rmw.topic_keyexpr(self.domain, topic, msgtype, self.distro)

    def publisher(self, topic: str, msgtype: str, qos: rmw.Qos) -> Publisher:
        """A publisher of ``msgtype`` on ``topic`` (fully qualified against the namespace)."""
        topic = rmw.fully_qualified(topic, self.namespace)
        eid = self._token("MP", topic, msgtype, qos)
        pub = Publisher(self, topic, msgtype, qos, eid)
        self._endpoints.append(pub)
        return pub

    def subscribe(self, topic: str, msgtype: str, qos: rmw.Qos, callback):
        """Call ``callback(topic, payload: bytes, arrival_ns, attachment: bytes | None)``."""
        import zenoh
        import zenoh.ext as zext

        topic = rmw.fully_qualified(topic, self.namespace)
        self._token("MS", topic, msgtype, qos)
        key = self.keyexpr(topic, msgtype)

        def on_sample(sample):
            att = sample.attachment
            att = att.to_bytes() if att is not None else None
            callback(topic, sample.payload.to_bytes(), time.monotonic_ns(), att)

        if qos.transient_local:
            history = zext.HistoryConfig(detect_late_publishers=True, max_samples=qos.depth)
            sub = zext.declare_advanced_subscriber(self.session, key, on_sample, history=history)
        else:
            sub = self.session.declare_subscriber(key, zenoh.handlers.Callback(on_sample))
        self._endpoints.append(sub)
        return sub

    def close(self) -> None:
        for e in self._endpoints:
            try:
                e.undeclare()
            except Exception:  # already undeclared by the session
                pass
        for tok in self._tokens:
            try:
                tok.undeclare()
            except Exception:
                pass
        self.session.close()


class Publisher:
    """A publisher whose samples carry rmw_zenoh's attachment (sequence, time, GID)."""

    def __init__(self, node: Node, topic: str, msgtype: str, qos: rmw.Qos, eid: int) -> None:
        import zenoh
        import zenoh.ext as zext

        self.topic, self.msgtype, self.qos = topic, msgtype, qos
        key = node.keyexpr(topic, msgtype)
        # rmw's GID: 16 bytes unique to this publisher (session id + entity id, hashed).
        self.gid = hashlib.sha256(f"{node.zid}/{eid}".encode()).digest()[:16]
        self._seq = 0
        kw = {
            "congestion_control": zenoh.CongestionControl.BLOCK
            if qos.reliable
            else zenoh.CongestionControl.DROP,
            "reliability": zenoh.Reliability.RELIABLE
            if qos.reliable
            else zenoh.Reliability.BEST_EFFORT,
        }
        if qos.transient_local:
            self._pub = zext.declare_advanced_publisher(
                node.session,
                key,
                cache=zext.CacheConfig(max_samples=qos.depth),
                publisher_detection=True,
                **kw,
            )
        else:
            self._pub = node.session.declare_publisher(key, **kw)

    @property
    def matched(self) -> bool:
        """Whether a subscription matches (False when the transport cannot tell)."""
        # zenoh's MatchingStatus object is always truthy: its ``matching`` field is the answer
        status = getattr(self._pub, "matching_status", None)
        return bool(getattr(status, "matching", False))

    def put(self, payload: bytes) -> None:
        self._seq += 1
        att = rmw.attachment(self._seq, time.time_ns(), self.gid)
        self._pub.put(bytes(payload), attachment=att)

    def undeclare(self) -> None:
        self._pub.undeclare()


def wait_matched(publishers, timeout_s: float) -> bool:
    """Wait (bounded) until every publisher has a matching subscription; True if they do."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if all(p.matched for p in publishers):
            return True
        time.sleep(0.01)
    return all(p.matched for p in publishers)
