"""rmw_zenoh's wire format, spoken from Python without a ROS installation.

What a ROS 2 node on ``rmw_zenoh_cpp`` puts on Zenoh (rmw_zenoh ``docs/design.md``: "Topic and
Service name mapping to Zenoh key expressions", "Graph Cache", "Publishers", "Quality of
Service"; the attachment of ``rmw_zenoh_cpp/src/detail/attachment_helpers``):

* **data key expression** ``<domain_id>/<topic without its leading '/'>/<DDS type name>/<type
  hash>``, e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...1a18``. The DDS type
  name of ``pkg/msg/Name`` is ``pkg::msg::dds_::Name_``. The type hash is ``RIHS01_`` and the
  SHA-256 of the type description (REP 2011; computed by rosbags' ``hash_rihs01``) from Iron
  on; Humble's rmw_zenoh puts ``TypeHashNotSupported`` there.
* **payload**: the message in CDR, little endian, with its 4-byte encapsulation header (what
  rosbags' ``serialize_cdr`` writes and a bag stores).
* **attachment** of every sample: ``sequence_number`` (int64), ``source_timestamp`` (int64, ns)
  and the publisher's 16-byte GID, in Zenoh's serialisation (little-endian integers; the GID a
  sequence: LEB128 length 16, then the bytes): 33 bytes.
* **liveliness tokens** (the graph cache): ``@ros2_lv/<domain>/<session id>/<node id>/<entity
  id>/<kind>/<enclave>/<namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]``, kinds ``NN``
  (node), ``MP`` (publisher), ``MS`` (subscription); ``/`` inside a name is written ``%`` and an
  empty name is ``%``.
* **QoS** in a token: ``reliability:durability:history,depth:deadline:lifespan:liveliness``
  (deadline, lifespan and liveliness lease as ``sec,nsec``), each value written only when it
  differs from ``rmw_qos_profile_default`` (reliable, volatile, keep last 10): the default
  profile is ``::,:,:,:,,``. Enum values are rmw's: reliability 1 reliable / 2 best effort,
  durability 1 transient local / 2 volatile, history 1 keep last / 2 keep all.
* **transient local** (``/tf_static``): the publisher keeps its last samples in a Zenoh cache
  that late-joining subscriptions query (zenoh-ext's advanced publisher / subscriber).

The Zenoh session configuration follows rmw_zenoh's rules: ``ZENOH_SESSION_CONFIG_URI`` (a
Zenoh config file) if set, else rmw_zenoh's session defaults (peer, connect to
``tcp/localhost:7447``, multicast scouting off); then ``ZENOH_CONFIG_OVERRIDE``
(``key=value;key=value`` in JSON5, applied on top); then the ``live:`` block's keys.
``ROS_DOMAIN_ID`` gives the domain (0 when unset).
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass

from odofuse.errors import ConfigError

#: Humble's rmw_zenoh writes this in place of a type hash.
NO_TYPE_HASH = "TypeHashNotSupported"
#: rmw_zenoh's liveliness admin space.
ADMIN_SPACE = "@ros2_lv"
#: rmw_zenoh's session defaults (its DEFAULT_RMW_ZENOH_SESSION_CONFIG.json5, the keys we set).
RMW_SESSION_DEFAULTS = {
    "mode": "peer",
    "connect/endpoints": ["tcp/localhost:7447"],
    "scouting/multicast/enabled": False,
    # the transient-local cache (zenoh-ext's advanced publisher) needs timestamps
    "timestamping/enabled": {"router": True, "peer": True, "client": True},
}


@dataclass(frozen=True)
class Qos:
    """The QoS of one endpoint, as rmw's enums (see the module doc)."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10

    def keyexpr(self) -> str:
        """rmw_zenoh's QoS string (defaults left empty)."""
        rel = "" if self.reliable else "2"
        dur = "1" if self.transient_local else ""
        depth = "" if self.depth == 10 else str(int(self.depth))
        return f"{rel}:{dur}:,{depth}:,:,:,,"


def dds_type_name(msgtype: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_``."""
    pkg, sub, name = msgtype.split("/")
    return f"{pkg}::{sub}::dds_::{name}_"


def typestore(distro: str):
    """rosbags' type store of a ROS 2 distribution (its message definitions)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(getattr(Stores, f"ROS2_{distro.upper()}", Stores.ROS2_JAZZY))


def type_hash(msgtype: str, distro: str) -> str:
    """``RIHS01_<sha256>`` of the type description (REP 2011), or Humble's placeholder."""
    if distro == "humble":
        return NO_TYPE_HASH
    return typestore(distro).hash_rihs01(msgtype)


def mangle(name: str) -> str:
    """A ROS name inside a liveliness token: ``/`` -> ``%``; empty -> ``%``."""
    return name.replace("/", "%") if name else "%"


def fully_qualified(topic: str, namespace: str = "") -> str:
    """``/ns/topic`` of a relative or absolute topic name."""
    if topic.startswith("/"):
        return topic
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{topic}"


def topic_keyexpr(domain: int, topic: str, msgtype: str, distro: str) -> str:
    """The data key expression of a topic (see the module doc)."""
    name = topic.strip("/")
    return f"{int(domain)}/{name}/{dds_type_name(msgtype)}/{type_hash(msgtype, distro)}"


def node_token(domain: int, zid: str, node_id: int, namespace: str, node: str) -> str:
    """The ``NN`` liveliness token of a node."""
    ns = mangle("/" + namespace.strip("/") if namespace.strip("/") else "")
    return f"{ADMIN_SPACE}/{int(domain)}/{zid}/{node_id}/{node_id}/NN/%/{ns}/{node}"


def entity_token(
    domain: int,
    zid: str,
    node_id: int,
    entity_id: int,
    kind: str,
    namespace: str,
    node: str,
    topic: str,
    msgtype: str,
    distro: str,
    qos: Qos,
) -> str:
    """The ``MP``/``MS`` liveliness token of a publisher or subscription."""
    if kind not in ("MP", "MS"):
        raise ValueError(f"entity kind must be MP or MS, got {kind!r}")
    ns = mangle("/" + namespace.strip("/") if namespace.strip("/") else "")
    return (
        f"{ADMIN_SPACE}/{int(domain)}/{zid}/{node_id}/{entity_id}/{kind}/%/{ns}/{node}/"
        f"{mangle(topic)}/{dds_type_name(msgtype)}/{type_hash(msgtype, distro)}/{qos.keyexpr()}"
    )


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte rmw_zenoh attachment of one sample."""
    if len(gid) != 16:
        raise ValueError(f"a GID has 16 bytes, got {len(gid)}")
    return struct.pack("<qqB", int(sequence_number), int(source_timestamp_ns), 16) + bytes(gid)


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """``(sequence_number, source_timestamp_ns, gid)`` of an rmw_zenoh attachment."""
    data = bytes(data)
    if len(data) != 33 or data[16] != 16:
        raise ValueError(f"not an rmw_zenoh attachment ({len(data)} bytes)")
    seq, ts = struct.unpack_from("<qq", data)
    return seq, ts, data[17:]


def domain_id(configured: int | None, source: str = "<config>") -> int:
    """``live.domain_id``, else ``ROS_DOMAIN_ID``, else 0."""
    if configured is not None:
        return int(configured)
    raw = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not raw:
        return 0
    if not raw.isdigit() or int(raw) > 232:
        raise ConfigError(f"ROS_DOMAIN_ID={raw!r} is not a domain id (0-232)", source, "live")
    return int(raw)


def session_config(live, source: str = "<config>"):
    """The ``zenoh.Config`` of a ROS 2 node on rmw_zenoh, with the ``live:`` block on top."""
    import zenoh

    uri = os.environ.get("ZENOH_SESSION_CONFIG_URI", "").strip()
    if uri:
        try:
            conf = zenoh.Config.from_file(uri)
        except Exception as exc:  # zenoh raises ZError with its parser's message
            raise ConfigError(f"ZENOH_SESSION_CONFIG_URI={uri}: {exc}", source, "live") from None
    else:
        conf = zenoh.Config()
        for key, value in RMW_SESSION_DEFAULTS.items():
            conf.insert_json5(key, json.dumps(value))
    for item in filter(None, os.environ.get("ZENOH_CONFIG_OVERRIDE", "").split(";")):
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(
                f"ZENOH_CONFIG_OVERRIDE item {item!r} is not key=value", source, "live"
            )
        try:
            conf.insert_json5(key.strip(), value.strip())
        except Exception as exc:
            raise ConfigError(f"ZENOH_CONFIG_OVERRIDE {item!r}: {exc}", source, "live") from None
    # the advanced publisher of /tf_static needs timestamps, whatever the file says
    conf.insert_json5(
        "timestamping/enabled", json.dumps(RMW_SESSION_DEFAULTS["timestamping/enabled"])
    )
    if live.mode is not None:
        conf.insert_json5("mode", json.dumps(live.mode))
    if live.connect is not None:
        conf.insert_json5("connect/endpoints", json.dumps(list(live.connect)))
    if live.listen is not None:
        conf.insert_json5("listen/endpoints", json.dumps(list(live.listen)))
    if live.multicast_scouting is not None:
        conf.insert_json5("scouting/multicast/enabled", json.dumps(live.multicast_scouting))
    return conf
